"""Finished one-off studies, kept rerunnable (``python -m research.<name>``); research/README.md lists them."""
