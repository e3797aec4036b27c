import sys

from mavadrc.cli.main import main

sys.exit(main())
