"""`python -m demo` is the `demo` command."""

import sys

from demo.cli.main import main

sys.exit(main())
