"""The protocol library, pure: golden vectors, decoder tables and properties."""
