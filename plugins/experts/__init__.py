"""Built-in expert plugins (grasp-execution policies), one folder each; see docs/experts.md."""
