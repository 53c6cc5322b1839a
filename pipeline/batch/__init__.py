"""Batch runs: a plan file (scenes x simulation settings x methods) -> tasks on Dask distributed.

plan.py (plan file -> tasks, content keys), execute.py (one task on a worker: its stage as a subprocess,
its record written last), runner.py (the Dask cluster, progress, collection), results.py (table and
summary page), build_scene.py (the .blend of a procedural scene), cli.py (`platolidar batch`).
Nothing here imports bpy or torch: stages run as subprocesses. Usage and deployment: docs/batch.md.
"""
