"""``python -m aspp``: print the record table (docs/interface.md's copy is generated from it)."""

from .records import markdown_table

print(markdown_table())
