import sys

from racerlab.cli import main

sys.exit(main())
