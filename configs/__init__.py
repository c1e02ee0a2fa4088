"""The YAML configs hispo-pl ships, as package data (``hispo-pl config list``)."""
