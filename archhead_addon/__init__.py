"""ArchHead core (never imports bpy)."""
