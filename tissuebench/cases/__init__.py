"""The case catalogue: scene builders and mesh generators."""
