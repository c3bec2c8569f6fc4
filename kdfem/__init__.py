"""kdfem: passive deformable objects (tetrahedral FEM) driven by an animated head, and their KD windows."""
