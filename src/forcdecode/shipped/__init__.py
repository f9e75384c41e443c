"""Trained models shipped with the package (package data, ``laptop/``): see ``forcdecode.learn.shipped``."""
