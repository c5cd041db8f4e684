"""Built-in GES-UniGrasp plugins: one folder per hand, simulator or gate."""
