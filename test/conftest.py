"""Hypothesis profiles: what randomness the property tests may use.

- "ci": derandomize=True (examples derived from each test's source, the same on every run
  and every clone), no example database (nothing carried between runs), print_blob=True (a
  failure prints the exact reproduction blob). Loaded whenever the CI environment variable
  is set, so a submission is never rejected by chance.
- "dev": hypothesis's defaults (random, with the local example database); the default
  elsewhere.
- "deep": many more random examples, for people to run (`make test-deep`) to search for
  defects that the fixed CI examples do not reach.
HYPOTHESIS_PROFILE selects one explicitly when CI is not set.
"""
import os

from hypothesis import HealthCheck, settings

settings.register_profile('ci', derandomize=True, database=None, print_blob=True)
settings.register_profile('dev')
settings.register_profile('deep', max_examples=2000, derandomize=False,
                          suppress_health_check=[HealthCheck.too_slow])

if os.environ.get('CI'):
    settings.load_profile('ci')
else:
    settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'dev'))


def pytest_collection_modifyitems(config, items):
    # `make test-deep` selects the property tests with -m property; hypothesis marks them.
    for item in items:
        if getattr(getattr(item, 'obj', None), 'is_hypothesis_test', False):
            item.add_marker('property')
