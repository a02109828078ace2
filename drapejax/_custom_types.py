"""Shape aliases used across drapejax (jaxtyping)."""

from jaxtyping import Array, Bool, Float, Int

Points = Float[Array, "n 3"]
Faces = Int[Array, "m 3"]
Scalar = Float[Array, ""]
VertexMask = Bool[Array, " n"]

__all__ = ["Array", "Bool", "Float", "Int", "Points", "Faces", "Scalar", "VertexMask"]
