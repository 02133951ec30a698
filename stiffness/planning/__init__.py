"""Design layer: measurement plans, synthetic campaigns and the experiment-design workflow."""
