"""Small shared utilities, each in one leaf module that imports nothing else of meshadv.

* :mod:`meshadv.util.atomic` -- atomic file writes (temporary file in the target folder, fsync, rename);
* :mod:`meshadv.util.json_file` -- reading a JSON file, with errors naming it;
* :mod:`meshadv.util.png` -- saving images as PNG files (atomically);
* :mod:`meshadv.util.markdown` -- Markdown tables;
* :mod:`meshadv.util.paths` -- paths written relative to the folder that holds them;
* :mod:`meshadv.util.spherical` -- the spherical-direction formula of the NMR camera convention.
"""
