"""Evaluation that sees what a user sees: object metrics, shaded renders, the summary page.

torch_recon.evaluate keeps the whole-scene depth metrics; this package adds the per-object surface
metrics (objects.py) on the surface distances both share (surface.py: Chamfer, F-score), normal-shaded renders and error images (render.py) and the summary page (report.py).
"""
