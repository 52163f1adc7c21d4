"""Fleet analysis: every flight of a campaign through the estimators, and gain sweeps, as tasks
on a Dask cluster (a LocalCluster by default). Each task reads, processes and writes one flight
with the code `gcs replay` and what-if use, and returns only a small summary."""
