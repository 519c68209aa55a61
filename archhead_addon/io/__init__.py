"""File I/O shared by every format: input errors, the allow-list unpickler, atomic writes."""
