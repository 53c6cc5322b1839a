"""CLI subcommands of `python -m torch_recon`, one module each (see torch_recon/cli.py)."""
