"""FunREC's tests. A package so that shared builders import as ``tests.helpers.<concept>`` from any
test file, however pytest is started (pytest puts the repository root on sys.path)."""
