"""The drivers behind the command line's everyday commands: evaluate a stream, named sources, ``swarmloc team``'s
scoring, ``compare``, ``consistency``, MRCLAM, your own robots' files, anonymous association, mapping, output and
progress, and the thesis sec. 5.1 demo of ``swarmloc demo`` (:mod:`.thesis_demo`). The research studies (thesis
reproduction, leave-one-dataset-out, the 3-D study, benchmarks' helpers) are a package of their own in the
repository, ``swarmloc_studies``, which imports swarmloc; nothing in swarmloc imports it.
"""
