import json
import os
import re
import shlex
import sys
from pathlib import Path

from forcdecode.core.io import write_json
from snakemake.settings.types import DeploymentMethod
from snakemake.utils import validate

# Stops before any job runs, naming the offending key; fills in the schema's defaults.
validate(config, "../schemas/config.schema.yaml", set_default=True)

# sections that only the learning and loop stages read (kept out of the dataset's config.json)
STAGE_SECTIONS = ("learning", "loop")
# sections that only optional rules read (kept out of config.json and learning.json: changing them
# reruns only their own rule, passed to it as a parameter)
OPTION_SECTIONS = ("posterior",)
RESULTS = config["results_dir"].rstrip("/")
LEARN_PARAMETERS = config["learning"]["parameters"]
N_SCREEN_CHUNKS = -(-config["n_samples"] // config["chunk_size"])
SCREEN_CHUNKS = [f"{RESULTS}/screen/chunk_{k:04d}.parquet" for k in range(N_SCREEN_CHUNKS)]

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


def family_chunks(wildcards):
    """Family chunk files, known once the screening checkpoint has run (read once)."""
    selection = checkpoints.select.get().output[0]
    with open(selection) as handle:
        chunks = json.load(handle)["chunks"]
    return [f"{RESULTS}/families/chunk_{int(k):04d}.h5" for k in sorted(chunks, key=int)]


# chunk numbers are written with four digits; a parameter is one of the learned ones
wildcard_constraints:
    chunk=r"\d{4}",
    parameter="|".join(re.escape(p) for p in LEARN_PARAMETERS),
