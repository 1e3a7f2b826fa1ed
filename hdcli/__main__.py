"""``python -m hdcli``: the ``hd`` command."""

from hdcli.cli import main

main()
