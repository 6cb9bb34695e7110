"""The manipulation domain of the paper's App. C: gripper, basket, three cubes."""
