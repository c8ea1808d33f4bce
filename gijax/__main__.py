import sys

from gijax.cli import main

sys.exit(main())
