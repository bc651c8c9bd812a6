import sys

from diffblur.app.cli import main

sys.exit(main())
