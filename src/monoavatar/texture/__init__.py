"""texture stage."""
