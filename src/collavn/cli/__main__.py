"""``python -m collavn.cli …`` (e.g. under ``torchrun``)."""

from collavn.cli import main

raise SystemExit(main())
