"""``forcdecode predict``: a FORC file or image and M_s in; each parameter with its uncertainty out."""

from .cli import add_predict_arguments as add_arguments, run_predict as run
