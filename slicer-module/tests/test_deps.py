"""ResectaLib.deps: supported Slicer versions, version ranges (never a downgrade), the install
flow after confirmation with list arguments, and where the client is imported from."""

import sys

import pytest

from ResectaLib import deps

R = deps.Requirement.parse
REQS = [R("grpcio>=1.85.1,<2"), R("protobuf>=7.35.1,<8"), R("numpy>=1.26,<3")]


@pytest.fixture
def versions(monkeypatch):
    """A fake environment: {distribution: version}; `deps` reads installed versions from it."""
    env = {"grpcio": "1.85.3", "protobuf": "7.36.2", "numpy": "2.4.6"}
    monkeypatch.setattr(deps, "installed_version", env.get)
    return env


def test_requirements_file_is_the_one_list_of_ranges():
    reqs = deps.requirements()
    assert {r.name for r in reqs} == {"grpcio", "protobuf", "numpy"}
    for r in reqs:
        ops = {op for op, _ in r.bounds}
        assert ops & {">=", ">"} and ops & {"<", "<="}, f"{r} is not a closed range"


@pytest.mark.parametrize("line", ["grpcio==1.85.3", "numpy", "numpy>=1.26<3", "grpcio~=1.85",
                                  "protobuf>=7 ; python_version<'3'", ">=1.0"])
def test_pins_unbounded_and_unreadable_lines_are_refused(line):
    with pytest.raises(ValueError):
        R(line)


def test_parse_round_trips():
    assert str(R(" protobuf >= 7.35.1 , < 8 ")) == "protobuf>=7.35.1,<8"


def test_nothing_to_do_inside_the_ranges(versions):
    assert deps.plan(REQS) == []


def test_missing_and_older_packages_are_installed_or_upgraded(versions):
    versions.pop("grpcio")
    versions["protobuf"] = "6.33.6"
    todo = deps.plan(REQS)
    assert [(str(i.requirement), i.installed) for i in todo] == [
        ("grpcio>=1.85.1,<2", None), ("protobuf>=7.35.1,<8", "6.33.6")]
    assert [str(i) for i in todo] == ["grpcio>=1.85.1,<2 (not installed)",
                                      "protobuf>=7.35.1,<8 (installed 6.33.6: upgraded)"]


def test_a_newer_shared_package_is_a_conflict_never_a_downgrade(versions):
    versions["protobuf"] = "8.0.0"
    with pytest.raises(deps.DependencyConflict) as e:
        deps.plan(REQS)
    assert "protobuf 8.0.0 is installed; Resecta needs protobuf>=7.35.1,<8" in str(e.value)
    assert "does not downgrade" in str(e.value)


def test_without_packaging_the_numeric_comparison_gives_the_same_answers(monkeypatch, versions):
    monkeypatch.setitem(sys.modules, "packaging.version", None)  # import fails
    assert deps._version_key("8.0") == deps._version_key("8") == (8,)
    assert R("protobuf>=7.35.1,<8").violated("7.36.2") == []
    assert R("protobuf>=7.35.1,<8").violated("8.0.0") == ["<"]
    assert R("protobuf>=7.35.1,<8").violated("7.35.0") == [">="]
    versions["numpy"] = "3.0.0rc1"
    with pytest.raises(deps.DependencyConflict):
        deps.plan(REQS)


def test_ensure_installed_asks_then_installs_with_one_argument_per_requirement(versions):
    versions.pop("grpcio")
    versions["numpy"] = "1.21.0"
    asked, installed = [], []

    def install(args):
        installed.append(args)
        versions.update(grpcio="1.85.3", numpy="2.4.6")

    assert not deps.ensure_installed(lambda lines: asked.append(lines) or False, install)
    assert installed == [], "declined: nothing installed"
    assert deps.ensure_installed(lambda lines: True, install)
    assert asked == [["grpcio>=1.85.1,<2 (not installed)", "numpy>=1.26,<3 (installed 1.21.0: upgraded)"]]
    assert installed == [["grpcio>=1.85.1,<2", "numpy>=1.26,<3"]]


def test_ensure_installed_uses_slicers_pip_install_with_a_list(monkeypatch, versions):
    import slicer.util

    versions.pop("numpy")
    calls = []
    monkeypatch.setattr(slicer.util, "pip_install", lambda req, **kw: calls.append(req), raising=False)
    with pytest.raises(RuntimeError, match="still not met: numpy"):
        deps.ensure_installed(lambda lines: True)  # the fake pip installs nothing
    assert calls == [["numpy>=1.26,<3"]]


def test_a_conflict_is_raised_before_anything_is_asked(versions):
    versions["grpcio"] = "2.0.0"
    with pytest.raises(deps.DependencyConflict, match="grpcio 2.0.0"):
        deps.ensure_installed(lambda lines: pytest.fail("must not ask"), lambda a: pytest.fail("no pip"))


def test_in_this_environment_everything_is_there():
    assert deps.plan() == []
    assert deps.ensure_installed(lambda _lines: pytest.fail("nothing should be asked"))


@pytest.mark.parametrize("slicer,python", [("5.10.0", (3, 12)), ("5.11.0-2026-01-15", (3, 12)),
                                           ("6.0.1", (3, 13))])
def test_supported_slicers(slicer, python):
    deps.check_slicer_version(slicer, python)


@pytest.mark.parametrize("slicer,python", [("5.8.1", (3, 9)), ("5.4.0", (3, 9)), ("5.9.0", (3, 12)),
                                           ("5.10.0", (3, 9))])
def test_older_slicers_are_refused_with_the_reason(slicer, python):
    with pytest.raises(deps.UnsupportedSlicer) as e:
        deps.check_slicer_version(slicer, python)
    text = str(e.value)
    assert "3D Slicer 5.10 or newer" in text and slicer in text and f"{python[0]}.{python[1]}" in text


def test_a_version_that_is_not_one_is_an_error():
    with pytest.raises(ValueError):
        deps.check_slicer_version("nightly")


def test_the_client_comes_from_the_checkout_and_is_put_first_once(monkeypatch):
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p != str(deps.CHECKOUT_CLIENT)])
    assert deps.client_path() == deps.CHECKOUT_CLIENT  # nothing is shipped in a checkout
    assert deps.use_client() == deps.CHECKOUT_CLIENT
    deps.use_client()
    assert sys.path[0] == str(deps.CHECKOUT_CLIENT) and sys.path.count(str(deps.CHECKOUT_CLIENT)) == 1


def test_the_shipped_client_wins_and_a_missing_one_is_a_clear_error(monkeypatch, tmp_path):
    shipped = tmp_path / "Python"
    (shipped / "resecta_client").mkdir(parents=True)
    (shipped / "resecta_client" / "__init__.py").write_text("")
    monkeypatch.setattr(deps, "BUNDLED_CLIENT", shipped)
    assert deps.client_path() == shipped
    monkeypatch.setattr(deps, "BUNDLED_CLIENT", tmp_path / "nothing")
    monkeypatch.setattr(deps, "CHECKOUT_CLIENT", tmp_path / "nothing either")
    with pytest.raises(deps.MissingClient, match="resecta client is missing"):
        deps.client_path()
