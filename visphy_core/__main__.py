"""`python -m visphy_core <hydra overrides>`, or a subcommand: plugins, setup, build-dataset."""

import sys

from visphy_core.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
