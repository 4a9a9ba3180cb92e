"""tron1cli: LIPM-guided perceptive locomotion for the LimX TRON1 point-foot biped on MuJoCo."""

__version__ = "0.1.0"
