"""The Examples sections of the public API's docstrings run and print what they show (numpydoc examples as
doctests; a line marked ``+SKIP`` is shown, not run)."""

import doctest
import inspect

import pytest

import bayescal


def _documented():
    """Public names whose docstring, or whose public methods' docstrings, hold an Examples section."""
    out = []
    for name in bayescal.__all__:
        obj = getattr(bayescal, name)
        targets = [(name, obj)]
        if inspect.isclass(obj):
            targets += [(f"{name}.{m}", getattr(obj, m)) for m in vars(obj) if not m.startswith("_")]
        out += [(label, o) for label, o in targets if "Examples\n" in (inspect.getdoc(o) or "")]
    return out


EXAMPLES = _documented()


def test_the_public_api_shows_examples():
    assert len(EXAMPLES) >= 45, [label for label, _ in EXAMPLES]


@pytest.mark.parametrize("label, obj", EXAMPLES, ids=[label for label, _ in EXAMPLES])
def test_the_example_runs_as_shown(label, obj):
    finder = doctest.DocTestFinder(recurse=False)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = finder.find(obj, label, globs={})
    assert tests and tests[0].examples, label
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{label}: {result.failed} of {result.attempted} examples failed"
