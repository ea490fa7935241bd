"""The flake finder's reading of pytest's JUnit XML and its table (make flakes runs the tests)."""
from flake_finder import markdown, outcomes, table

JUNIT = '''<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest">
<testcase classname="test.test_a" name="test_one" time="1.0"/>
<testcase classname="test.test_a" name="test_two" time="1.0">
<failure message="AssertionError: late&#10;more">x</failure></testcase>
<testcase classname="test.test_b.TestC" name="test_three" time="0.1"><skipped message="no mono">s</skipped></testcase>
</testsuite></testsuites>'''


def test_each_runs_outcomes_and_the_pass_rate_per_test(tmp_path):
    (tmp_path / 'junit.xml').write_text(JUNIT)
    first = outcomes(tmp_path / 'junit.xml')
    assert first == {'test.test_a::test_one': ('passed', ''),
                     'test.test_a::test_two': ('failed', 'AssertionError: late'),
                     'test.test_b.TestC::test_three': ('skipped', 'no mono')}
    second = dict(first, **{'test.test_a::test_two': ('passed', '')})
    rows = table([{'run': 1, 'results': first}, {'run': 2, 'results': second}])
    assert rows[0]['test'] == 'test.test_a::test_two' and (rows[0]['passes'], rows[0]['failures']) == (1, 1)
    assert rows[0]['failed_in'] == [1]
    text = markdown(rows, [{'run': 1, 'seconds': 3.0, 'rc': 1}, {'run': 2, 'seconds': 3.0, 'rc': 0}], load=2)
    assert '2 tests ran, 1 failed at least once.' in text and '3 passes of 4 test runs.' in text
    assert '| test.test_a::test_two | 2 | 1 | 1 | 1 | AssertionError: late |' in text
    assert outcomes(tmp_path / 'absent.xml') == {}
