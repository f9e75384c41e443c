# forcdecode main job: config -> parameter draw -> screening -> FORC families -> dataset -> Alice/Bob
# per parameter -> metrics and figures.
# Rules live in workflow/rules/, one file per stage; they call the package's CLI (no physics here).
import os

# the laptop default, found next to this Snakefile (so --directory elsewhere works too)
configfile: os.path.join(workflow.basedir, "config", "config.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/draw.smk"
include: "workflow/rules/screen.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/merge.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/learn.smk"


localrules: all


rule all:
    input:
        rules.merge.output,
        rules.figure1.output,
        rules.evaluate.output,
        rules.closed_loop.output,
    default_target: True
