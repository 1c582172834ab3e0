"""world: where observations come from.

Modules (import them directly; nothing is imported or built here):

- ``dashtraj.world.xodr_writer``: typed OpenDRIVE 1.4 records and a deterministic writer.
- ``dashtraj.world.towns``: built-in towns (``TOWNS``, ``build_town``, ``town_path``).
- ``dashtraj.world.catalog``: the vehicle catalog (models, paint colours, identities).
"""
