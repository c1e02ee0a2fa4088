"""The notebook hispo-pl ships, as package data (``python -m hispo_pl.notebook`` runs it)."""
