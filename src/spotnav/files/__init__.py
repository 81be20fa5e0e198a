"""Reading and writing spotnav's files: setups, images, videos, truth, paths, known.csv and poses.csv.

A module per kind of file: :mod:`~spotnav.files.images` (one image), :mod:`~spotnav.files.setup_files` (setups and
OpenCV camera files), :mod:`~spotnav.files.poses` (``poses.csv``, truth, known poses and paths),
:mod:`~spotnav.files.sequences` (frames read and written), with :mod:`~spotnav.files.capture` (OpenCV's captures)
and :mod:`~spotnav.files.decoder` (the video decoder process); :mod:`~spotnav.files.numbers` checks that a field is
a number before it is converted. Only this package, the experiments layer and the CLI touch the file system. Every
failure is a :class:`~spotnav.errors.SpotnavError` with a one-line message that names the file.
"""
