# gpja: reproduction workflow for "Geometric-Photometric Joint Alignment".
# Setup only: configuration, validation, includes and the default target.
# Each stage lives in workflow/rules/<stage>.smk; all logic lives in the gpja package.
from snakemake.exceptions import WorkflowError
from snakemake.utils import min_version, validate

from gpja.errors import InputError
from gpja.settings import check_config

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")
# method names against the registry and cross-field rules (one lambda per level, ...): every settings
# object is built once here, before any job
try:
    check_config(config)
except InputError as err:
    raise WorkflowError(f"invalid config: {err}") from None


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/register.smk"
include: "workflow/rules/baselines.smk"
include: "workflow/rules/metrics.smk"
include: "workflow/rules/reference.smk"
include: "workflow/rules/apply.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/report.smk"


rule all:
    input:
        all_targets,
    default_target: True
