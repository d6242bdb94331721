"""Episode datasets: `Episode`, the generator, episode files and the `Dataset` loader.

``episode.py`` (the data), ``generator.py`` (sampling), ``storage.py`` (files and
index), ``build.py`` (scenes × split → directory), ``command.py`` (CLI).
"""
