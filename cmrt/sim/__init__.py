"""A clip played and judged: the batched simulation (set-up, Python and compiled control loops), the fall
monitor, the objective and the robustness validation."""
