# forcdecode main job: config -> parameter draw -> screening -> FORC families -> dataset -> Alice/Bob
# per parameter -> metrics, figures and the closed loop. `snakemake --report results/report.zip`
# afterwards packs every figure and table with its caption into a browsable record of the run.
# Rules live in workflow/rules/, one file per stage; they call the package's CLI (no physics here).
import os

from snakemake.utils import min_version

min_version("9.0")


# the laptop default, found next to this Snakefile (so --directory elsewhere works too), read only when
# no --configfile is given: Snakemake would otherwise extend it by the command line's files, and a key
# that file leaves out would come from the laptop default, not from the schema (paper.yaml ran with the
# laptop's 16 grains instead of the schema's 255 until 2026-11-29). Overlays name it: --configfile
# config/config.yaml OVERLAY.
if not workflow.overwrite_configfiles:

    configfile: os.path.join(workflow.basedir, "config", "config.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/draw.smk"
include: "workflow/rules/screen.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/merge.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/learn.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/sealed.smk"


localrules:
    all,
    families_of_chunk,


rule all:
    default_target: True
    input:
        rules.merge.output,
        rules.select.output,
        rules.figure1.output,
        rules.evaluate.output,
        rules.closed_loop.output,
        rules.report_tables.output,
        # the joint posterior (its test and, with a sealed set, sealed figures)
        f"{RESULTS}/posterior/metrics.json",
