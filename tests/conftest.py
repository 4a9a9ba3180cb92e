import os

# keep test runs light on the 2-core machine
os.environ.setdefault("OMP_NUM_THREADS", "1")
