import json
import sys

from snakemake.utils import validate

# Stops before any job runs, naming the offending key; fills in the schema's defaults.
validate(config, "../schemas/config.schema.yaml", set_default=True)

# sections that only the learning and loop stages read (kept out of the dataset's config.json)
STAGE_SECTIONS = ("learning", "loop")
RESULTS = config["results_dir"].rstrip("/")
FORCDECODE = f"{sys.executable} -m forcdecode.cli"
N_SCREEN_CHUNKS = (config["n_samples"] + config["chunk_size"] - 1) // config["chunk_size"]
SCREEN_CHUNKS = [f"{RESULTS}/screen/chunk_{k:04d}.parquet" for k in range(N_SCREEN_CHUNKS)]
# one numba thread per job: parallelism comes from jobs (samples), not threads
ENV = "NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1"


def family_chunks(wildcards):
    """Family chunk files, known once the screening checkpoint has run (read once)."""
    selection = checkpoints.select.get().output[0]
    with open(selection) as handle:
        chunks = json.load(handle)["chunks"]
    return [f"{RESULTS}/families/chunk_{int(k):04d}.h5" for k in sorted(chunks, key=int)]
