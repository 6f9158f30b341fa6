# ReconDreamer experiment system: the paper's five tables, figures and report.
#   snakemake --cores 2                                   embedded synthetic benchmark (config/config.yaml)
#   snakemake --cores 2 --configfile config/quick.yaml    the same DAG at tiny sizes
#   snakemake --report results/report.html                the Snakemake report
#   snakemake --cores 2 --configfile config/foundation.yaml  the foundation weight set (weights/, GATES.md)
# Every job is one `recondreamer` command; see config/README.md.

import os

from snakemake.exceptions import WorkflowError
from snakemake.utils import min_version

from recondreamer.configs import DEFAULT_WORKFLOW_CONFIG, check_workflow_config, layer, read_yaml_mapping
from recondreamer.errors import RecondreamerError

min_version("9.0")


# config/config.yaml holds every key; --configfile files (and --config values), which Snakemake
# has already merged into `config`, set only what differs and are layered over it. Segment lists
# and local checkpoints replace the default's instead of merging with them (configs.WHOLE_MAPPINGS).
_default_config = os.path.join(workflow.basedir, DEFAULT_WORKFLOW_CONFIG)
_layered = layer(read_yaml_mapping(_default_config), config)
config.clear()
config.update(_layered)
try:  # a bad value is reported with the config file that set it
    check_workflow_config(config, os.path.join(workflow.basedir, "workflow/schemas/config.schema.yaml"), [_default_config, *workflow.configfiles])
except RecondreamerError as error:
    raise WorkflowError(str(error)) from None


# The repository, for workflow/envs/recondreamer.yaml (snakemake --use-conda installs this package from it).
os.environ.setdefault("RECONDREAMER_ROOT", workflow.basedir)

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
