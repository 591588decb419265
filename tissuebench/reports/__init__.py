"""Report builders and plots (written to an output folder, never into git)."""
