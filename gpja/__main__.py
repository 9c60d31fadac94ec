import sys

from gpja.cli import main

sys.exit(main())
