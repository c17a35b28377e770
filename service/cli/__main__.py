"""``python -m service.cli``: the ``dlo`` command line."""

from service.cli import main

main()
