"""The system file: YAML read and edited, its schema, its rules, its links' URLs, loaded into a System."""
