"""The names of ``tron1 eval``'s metrics, in table order, and the protocol's defaults the CLI shows
(light: the CLI builds its help from them without importing the env core). Their definitions:
:mod:`tron1cli.evaluation.protocol`."""

METRICS = (
    "success_rate",
    "orientation_error",
    "angular_velocity_error",
    "velocity_tracking_error",
    "reconstruction_error_cm",
    "exposure_s",
    "command_progress",
    "pitch_deg",
    "traverse_rate",
)
#: the metrics that are shares of envs, shown in %
PERCENT_METRICS = ("success_rate", "traverse_rate")

#: random terrain layouts drawn per level for an eval batch (the training bank draws 2): each env
#: stands on one of them, so a figure does not hinge on where a couple of tiles put their blocks
#: (discrete and rough; stairs and slopes have one layout however many are drawn). With 2, one
#: checkpoint's discrete success moved 48-62 % between eval seeds (sd 4.7 points over six seeds)
EVAL_LAYOUTS = 16
