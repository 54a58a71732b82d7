"""Worker roles: one interface per role, backends chosen by config in the role's factory."""
