# ReconDreamer experiment system: the paper's five tables, figures and report.
#   snakemake --cores 2                                   embedded synthetic benchmark (config/config.yaml)
#   snakemake --cores 2 --configfile config/quick.yaml    the same DAG at tiny sizes
#   snakemake --report results/report.html                the Snakemake report
#   snakemake --cores 2 --configfile config/foundation.yaml  the foundation weight set (weights/, GATES.md)
# Every job is one `recondreamer` command; see config/README.md.

from snakemake.utils import min_version, validate

min_version("9.0")


# The default config only when none is given on the command line: a --configfile is a complete
# config of its own (its segment mapping must not be merged with the default's).
if not workflow.overwrite_configfiles:

    configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/scenes.smk"
include: "workflow/rules/eval_models.smk"
include: "workflow/rules/pretrain.smk"
include: "workflow/rules/recon.smk"
include: "workflow/rules/restorer.smk"
include: "workflow/rules/recondreamer.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/foundation.smk"


rule all:
    input:
        final_outputs(),
    default_target: True
