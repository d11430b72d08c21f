"""The cloth model: the scene (physics and colliders), its energy, meshes and OBJ files."""
