import sys

from diffblur.cli import main

sys.exit(main())
