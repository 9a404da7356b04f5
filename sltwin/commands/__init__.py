"""One module per ``calib`` sub-command (``HELP``, ``add_arguments(parser)``, ``run(args)``);
``sltwin.cli`` registers them."""
