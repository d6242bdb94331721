"""Pictures: top-down maps, view strips, trajectory maps and episode animations."""
