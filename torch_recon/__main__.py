"""`python -m torch_recon <command> ...`: see `python -m torch_recon --help`."""

from .cli import main

raise SystemExit(main())
