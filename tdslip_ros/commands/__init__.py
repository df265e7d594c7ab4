"""The ``tdslip`` command (:mod:`.cli`) and its subcommands, one module each (``tdslip simulate`` is
:mod:`.simulate`, ...): each holds its argument parser and ``main(argv) -> int``, and composes the layers
below (model, bag, interfaces, nodes, analysis, studies, reporting) into what the command prints and
writes."""
