import sys

from recondreamer.cli import main

sys.exit(main())
