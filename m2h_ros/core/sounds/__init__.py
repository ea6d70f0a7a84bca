"""Sound library: real clips by category and class, heard/unheard splits."""
