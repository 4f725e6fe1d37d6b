"""``python -m aspp``: print the record table (README's copy is generated from it)."""

from .records import markdown_table

print(markdown_table())
