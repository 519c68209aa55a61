"""Training backend: the frame dataset (numpy only), the paper's losses, the two-stage loop.

Importing the package imports no torch; the modules that need it import it themselves.
"""
