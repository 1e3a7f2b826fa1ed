"""hdcore — what the three domain packages share: hd's errors (``hdcore.errors``), the settings'
metadata that makes the options of ``hd`` (``hdcore.setting``), the ranges of numeric settings
(``hdcore.bounds``), the storage layer every file goes through (``hdcore.storage``), a URL's
printable form without its secrets (``hdcore.redact``), the outcome
of a command (``hdcore.outcome``) and the lazy public names of a package (``hdcore.exports``).

It imports none of ``lidarsim``, ``hdlabels``, ``hdnet`` or ``hdcli``: the layers are
core → lidarsim → hdlabels → hdnet → hdcli (``tests/hdnet/test_import_graph.py``).
"""
