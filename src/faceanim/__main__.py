import sys

from faceanim.cli import main

sys.exit(main())
