"""hispo-pl: continual offline RL with hierarchical subspaces of policies, on Lightning."""

__version__ = "0.1.0"
