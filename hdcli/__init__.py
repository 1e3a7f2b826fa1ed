"""hdcli — the ``hd`` command line: the click commands (``hdcli.cli``), the options they share
(``hdcli.options``), the terminal (one-line errors, signals, ``-q``/``--json``, progress;
``hdcli.terminal``), one job per command that runs the domain packages' entry points and returns
what to print (``build_job``, ``label_job``, ``mosaic_job``, ``train_job``, ``eval_job``,
``detect_job``), the chains of commands (``chains``, ``pipeline``: ``hd demo``, ``hd reproduce``)
and the inspection of output directories (``inspection``: ``hd inspect``, ``hd verify``).

It is the top layer: hdcore → lidarsim → hdlabels → hdnet → hdcli; no domain package imports it.
"""
