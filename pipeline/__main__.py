import sys

from aftershock.pipeline.cli import main

sys.exit(main())
