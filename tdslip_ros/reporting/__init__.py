"""What the offline analysis and the studies both write and draw with, below both of them: output files
(:mod:`.output`), the figures' look (:mod:`.style`) and the grids of the paper's basin figures
(:mod:`.paper_grids`). No ROS here, and nothing of the analysis, the studies or the nodes."""
