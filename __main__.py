"""``python -m vertebra``: the ``vertebra`` command."""

import sys

from vertebra.cli.main import main

sys.exit(main())
