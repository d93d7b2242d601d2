"""The body: the planar humanoid (its MJCF model, joints, feet, poses) and the props it handles."""
