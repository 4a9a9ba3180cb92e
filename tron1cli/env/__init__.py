"""The one MuJoCo environment core shared by every command (train, eval, push-test, deploy-sim)."""
