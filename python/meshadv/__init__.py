"""meshadv: a fast CPU-first differentiable mesh renderer and the MeshAdv adversarial mesh toolkit."""

__version__ = "0.1.0"
