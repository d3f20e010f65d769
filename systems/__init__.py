"""LeafSystems of alight, one concept per module (see DESIGN.md)."""
