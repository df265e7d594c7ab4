"""Offline work, no rclpy: recorded runs against the analytic apex return map (decoding, records, strides,
compare, plots, report, controller_comparison), and the paper's figures and claims from the model core
(figures, paper_comparison with figure_claims and model_claims, simulate, rough_terrain). It does not import
the nodes or the studies."""
