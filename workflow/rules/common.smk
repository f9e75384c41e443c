import json
import os
import re
import shlex
import sys
from pathlib import Path

from forcdecode.config import dataset_config
from forcdecode.core.io import write_json
from snakemake.settings.types import DeploymentMethod
from snakemake.utils import validate

# Stops before any job runs, naming the offending key; fills in the schema's defaults.
validate(config, "../schemas/config.schema.yaml", set_default=True)

# sections that only the learning and loop stages read (kept out of the dataset's config.json)
STAGE_SECTIONS = ("learning", "loop")
# sections that only optional rules read (kept out of config.json and learning.json: changing them
# reruns only their own rule, passed to it as a parameter)
OPTION_SECTIONS = ("posterior", "fit", "sealed")
RESULTS = config["results_dir"].rstrip("/")
LEARN_PARAMETERS = config["learning"]["parameters"]
# Whole screening chunks of `chunk_size` consecutive sample ids, from first_sample_id on: a chunk's
# samples never depend on n_samples (rounded up to whole chunks), so growing n_samples (or a second
# id range) adds chunks and reuses every file of the chunks already run.
SIZE_KEYS = ("n_samples", "first_sample_id")
if config["first_sample_id"] % config["chunk_size"]:
    raise ValueError(
        f"first_sample_id ({config['first_sample_id']}) must be a multiple of chunk_size ({config['chunk_size']})"
    )
FIRST_CHUNK = config["first_sample_id"] // config["chunk_size"]
N_SCREEN_CHUNKS = -(-config["n_samples"] // config["chunk_size"])
CHUNKS = [f"{k:04d}" for k in range(FIRST_CHUNK, FIRST_CHUNK + N_SCREEN_CHUNKS)]
SCREEN_CHUNKS = [f"{RESULTS}/screen/chunk_{c}.parquet" for c in CHUNKS]
PARAM_CHUNKS = [f"{RESULTS}/params/chunk_{c}.parquet" for c in CHUNKS]

# The package's command line. With --use-conda (workflow/envs/forcdecode.yaml: its dependencies)
# it runs this checkout's source in that environment; otherwise the Python running Snakemake
# (the project's venv) runs the installed package.
if DeploymentMethod.CONDA in workflow.deployment_settings.deployment_method:
    FORCDECODE = f"PYTHONPATH={shlex.quote(os.path.join(workflow.basedir, 'src'))} python -m forcdecode.cli"
else:
    FORCDECODE = f"{shlex.quote(sys.executable)} -m forcdecode.cli"
# one numba/OpenMP thread per job: parallelism comes from jobs (samples), not threads
FORCDECODE_1T = f"NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 {FORCDECODE}"
CONDA_ENV = "../envs/forcdecode.yaml"


def chunk_family_parts(wildcards):
    """The family job files of one screening chunk (its passing samples in parts of
    family_chunk_size), known once that chunk's screening (a checkpoint) has run."""
    from forcdecode.dataset.stages import family_parts

    screen = checkpoints.screen.get(chunk=wildcards.chunk).output[0]
    parts = family_parts({"family_chunk_size": config["family_chunk_size"]}, screen)
    return [f"{RESULTS}/families/chunk_{wildcards.chunk}_{p:03d}.h5" for p in range(len(parts))]


# one list of family files per screening chunk (families_of_chunk writes it); merge depends on these
# statically, so a grown run schedules the new chunks' screening even when dataset.h5 exists
FAMILY_LISTS = [f"{RESULTS}/families/chunk_{c}.json" for c in CHUNKS]

# The sealed test set (learn/sealed.py): whole chunks of a separate id range, screened and simulated by
# the same rules, merged apart (sealed/dataset.h5) and read only by the scoring rules at the end
SEALED = config["sealed"]
if SEALED["first_sample_id"] % config["chunk_size"]:
    raise ValueError(
        f"sealed.first_sample_id ({SEALED['first_sample_id']}) must be a multiple of chunk_size ({config['chunk_size']})"
    )
FIRST_SEALED_CHUNK = SEALED["first_sample_id"] // config["chunk_size"]
SEALED_CHUNKS = [
    f"{k:04d}" for k in range(FIRST_SEALED_CHUNK, FIRST_SEALED_CHUNK + -(-SEALED["n_samples"] // config["chunk_size"]))
]
if set(SEALED_CHUNKS) & set(CHUNKS):
    raise ValueError(
        f"the sealed id range ({SEALED['first_sample_id']}, {SEALED['n_samples']} samples) overlaps the training range "
        f"({config['first_sample_id']}, {config['n_samples']} samples): move sealed.first_sample_id above it"
    )
SEALED_ON = bool(SEALED_CHUNKS)
# the posterior's test figures; with a sealed set, posterior_report adds its figures in metrics.json
POSTERIOR_TEST_METRICS = f"{RESULTS}/posterior/metrics_test.json" if SEALED_ON else f"{RESULTS}/posterior/metrics.json"


# chunk numbers are written with four digits; a parameter is one of the learned ones
wildcard_constraints:
    chunk=r"\d{4}",
    part=r"\d{3}",
    parameter="|".join(re.escape(p) for p in LEARN_PARAMETERS),
    draw=r"[A-Za-z0-9_-]+",
    cal=r"[A-Za-z0-9_-]+",


# The refinement of one family (workflow/rules/fit.smk, an option): where its rounds live
FIT = config["fit"]
FIT_ROUNDS = FIT["budget"] // FIT["round_size"]
if FIT["budget"] % FIT["round_size"]:
    raise ValueError(f"fit.budget ({FIT['budget']}) must be a multiple of fit.round_size ({FIT['round_size']})")
FIT_NAME = (
    Path(FIT["input"]).stem + (f"_sample{FIT['sample_id']}" if FIT["sample_id"] is not None else "")
    if FIT["input"]
    else "NONE"
)
FIT_DIR = f"{RESULTS}/fit/{FIT_NAME}"
FIT_WHICH = (
    f"--sample-id {FIT['sample_id']}"
    if FIT["sample_id"] is not None
    else (f"--Ms-kA-m {FIT['Ms_kA_m']}" if FIT["Ms_kA_m"] is not None else "")
)
# the box beyond the prior's bound (fit.extend_prior: NAME[=FACTOR] items, checked by the schema's pattern)
FIT_EXTEND = f"--extend-prior {' '.join(FIT['extend_prior'])}" if FIT["extend_prior"] else ""
# the calibrated check of the refined film against a reference of validation families (fit.predictive_reference)
FIT_CHECK = f"--predictive-reference {shlex.quote(FIT['predictive_reference'])}" if FIT["predictive_reference"] else ""
