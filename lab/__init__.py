"""This repository's own tools, beside the product and never shipped in its wheel: the paper's
figures (``paper.yaml``) and the tables that set ours beside them, the claims page, the reports
embedded in the docs pages, the manifests of the committed runs, and launches that record the
checkout's commit. It imports ``hispo_pl``; ``hispo_pl`` never imports it.

    python -m lab --help
"""
