"""Robot adapters: turn a chosen grasp point into motions (UR3, hexarotor)."""
