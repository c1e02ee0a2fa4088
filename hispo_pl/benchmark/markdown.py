"""Text from run files put into the Markdown pages hispo-pl writes, escaped so that a file's
content shows as text and never adds a column, a row, a line or code to the page."""

from __future__ import annotations


def cell(value: object) -> str:
    """``value`` as one line of Markdown text for a table cell or a list item: line breaks
    become spaces, ``|`` and backticks are escaped.

    Example:
        >>> cell("a|b\\n| x | `y`")
        'a\\\\|b \\\\| x \\\\| \\\\`y\\\\`'
    """
    text = " ".join(str(value).splitlines())
    return text.replace("|", "\\|").replace("`", "\\`")


def code_cell(value: object) -> str:
    """``value`` as inline code in a table cell (:func:`cell`'s escapes); plain text when it
    holds a backtick, which inline code cannot escape.

    Example:
        >>> code_cell("hispo-pl fit"), code_cell("a`b")
        ('`hispo-pl fit`', 'a\\\\`b')
    """
    return cell(value) if "`" in str(value) else f"`{cell(value)}`"
