"""Built-in gate plugins: CurveNet, PointNet++ (single-scale grouping) and the nearest-centroid baseline."""
