"""The pieces of ``scripts/make_results.py``: one module per part of the generated documentation."""
