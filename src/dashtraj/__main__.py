import sys

from dashtraj.cli import main

sys.exit(main())
