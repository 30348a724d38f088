"""One module per ``twinslam`` command: its parser (``register``) beside its handler (``run``)."""
