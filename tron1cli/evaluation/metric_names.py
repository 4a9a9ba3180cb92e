"""The names of ``tron1 eval``'s metrics, in table order (light: the CLI builds its help from them
without importing the env core). Their definitions: :mod:`tron1cli.evaluation.protocol`."""

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
