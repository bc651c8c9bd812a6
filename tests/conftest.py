from tests.backends import backend  # noqa: F401  (the fixture, for every test module)
