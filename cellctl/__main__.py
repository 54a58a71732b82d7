"""Console entry point: ``cellctl <command> …`` (see ``cellctl --help``)."""

from cellctl.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
