"""Stage splat: Gaussian-splatting models of the recorded street, in the workspace world frame."""
