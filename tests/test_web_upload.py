"""The browser client (#20) from nothing: on a server without sessions the page makes one,
uploads a phantom label map (file input, then a real drop), refuses a wrong role mapping before
sending anything, shows the server's summary, builds the models and shows them live without a
reload; a cancelled reconstruction leaves the session as it was and usable."""
import base64
import re

import pytest
import requests

from browser_harness import browser, empty  # noqa: F401 (fixtures)
from server_harness import Server

PHANTOM_MODELS = ["parenchyma", "portal_1", "tumor_1"]


@pytest.fixture
def phantom_file(tmp_path, resecta):
    resecta("phantom", "--out", tmp_path, "--preset", "small", "--json")
    return tmp_path / "phantom.nii.gz"


def models(page):
    return sorted(page.evaluate("window.resecta.models()"))


def session(server, sid):
    return requests.get(f"{server.http_url}/v1/sessions/{sid}", timeout=30).json()["session"]


def drop(page, path):
    """Drops `path` on the drop zone as a browser drop does: a DataTransfer holding the file."""
    page.evaluate(
        """([b64, name]) => {
          const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
          const dt = new DataTransfer();
          dt.items.add(new File([bytes], name));
          const zone = document.querySelector(".intake .drop");
          for (const type of ["dragenter", "dragover", "drop"])
            zone.dispatchEvent(
              new DragEvent(type, { dataTransfer: dt, bubbles: true, cancelable: true }));
        }""",
        [base64.b64encode(path.read_bytes()).decode(), path.name])


def test_a_session_made_in_the_page_gets_a_label_map_and_models(empty, browser, phantom_file):
    server = empty
    page = browser.new_page(viewport={"width": 1024, "height": 900})
    errors, uploads = [], []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("request", lambda r: uploads.append(r.url) if "/label-map" in r.url else None)
    page.goto(server.bound["page"])
    # No session on the server: the page offers to make one, and opens it.
    page.get_by_text("No session yet").wait_for()
    page.get_by_label("Display name").fill("upload test")
    page.get_by_role("button", name="Create and open").click()
    page.wait_for_url(re.compile(r"\?session=\w+"))
    sid = page.url.split("session=")[1]
    assert session(server, sid)["state"] == "SESSION_STATE_EMPTY"

    # A label in two roles is refused in the page: nothing is sent.
    page.locator(".intake input[type=file]").set_input_files(str(phantom_file))
    page.get_by_text("phantom.nii.gz (1.3 KiB, NIfTI)").wait_for()
    assert page.get_by_label("Parenchyma").input_value() == "1"  # the server's default roles
    assert page.get_by_label("Tumour", exact=True).input_value() == "2"
    page.get_by_label("Tumour", exact=True).fill("2, 3")
    page.get_by_role("button", name="Upload").click()
    page.get_by_text("Label 3 is in two roles: Tumour and Portal vein").wait_for()
    page.get_by_label("Hepatic veins").fill("4, x")
    page.get_by_role("button", name="Upload").click()
    page.get_by_text('Hepatic veins: "x" is not a label value').wait_for()
    assert uploads == []
    assert session(server, sid)["state"] == "SESSION_STATE_EMPTY"

    # Right roles: uploaded; the server's summary shows each label with its role and volume.
    page.get_by_label("Tumour", exact=True).fill("2")
    page.get_by_label("Hepatic veins").fill("4")
    page.get_by_role("button", name="Upload").click()
    page.get_by_text("48 × 40 × 26 voxels of 2.00 × 2.00 × 3.00 mm").wait_for()
    assert len(uploads) == 1
    rows = page.locator(".intake .summary tbody tr").all_inner_texts()
    assert [r.split("\t")[:2] for r in rows] == [
        ["1", "Parenchyma"], ["2", "Tumour"], ["3", "Portal vein"]]
    assert rows[1].split("\t")[3] == "2.2 ml"
    page.get_by_text("Hepatic veins label 4 is not in the file").wait_for()
    assert session(server, sid)["state"] == "SESSION_STATE_LABEL_MAP"

    # Reconstruct (MCSD): each model listed, then done; the live view shows them, no reload.
    page.get_by_label("Method").select_option("RECONSTRUCTION_METHOD_MCSD")
    page.get_by_role("button", name="Reconstruct").click()
    page.get_by_text("Built 3 models in").wait_for(timeout=120_000)
    listed = page.locator(".intake ul.models li").all_inner_texts()
    assert sorted(t.split(":")[0] for t in listed) == PHANTOM_MODELS
    assert all(t.endswith("(MCSD)") for t in listed)
    page.wait_for_function(f"() => window.resecta.models().length === {len(PHANTOM_MODELS)}")
    assert models(page) == PHANTOM_MODELS
    assert session(server, sid)["state"] == "SESSION_STATE_READY"
    # With models the section folds into "Label map and models" (left open to show the result).
    assert page.locator(".intake details > summary").inner_text() == "Label map and models"

    # A second reconstruction (PSR, seconds) cancelled from the page: the session is as it was.
    page.get_by_label("Method").select_option("RECONSTRUCTION_METHOD_PSR")
    page.get_by_role("button", name="Reconstruct").click()
    cancel = page.get_by_role("button", name="Cancel")
    cancel.click()
    page.get_by_text("Reconstruction cancelled").wait_for()
    assert session(server, sid)["state"] == "SESSION_STATE_READY"
    assert models(page) == PHANTOM_MODELS
    # ... and usable: the next reconstruction runs to its end.
    page.get_by_label("Method").select_option("RECONSTRUCTION_METHOD_MCSD")
    page.get_by_role("button", name="Reconstruct").click()
    page.get_by_text("Built 3 models in").wait_for(timeout=120_000)

    # A label map dropped on the zone replaces the old one: the models are gone from the view.
    drop(page, phantom_file)
    page.get_by_role("button", name="Upload").click()
    page.wait_for_function("() => window.resecta.models().length === 0")
    assert len(uploads) == 2
    assert session(server, sid)["state"] == "SESSION_STATE_LABEL_MAP"
    page.get_by_role("button", name="Reconstruct").wait_for()  # the form for the new label map
    assert not errors, errors
    page.close()


def test_an_upload_the_server_refuses_shows_its_problem(empty, browser, tmp_path):
    server = empty
    sid = requests.post(f"{server.http_url}/v1/sessions", json={"displayName": "refused"},
                        timeout=30).json()["session"]["id"]
    page = browser.new_page()
    page.goto(f"{server.bound['page']}?session={sid}")
    bad = tmp_path / "notes.nii"
    bad.write_bytes(b"not an image")
    # What the server says of it (it keeps the session empty: the page may send it again).
    r = requests.put(f"{server.http_url}/v1/sessions/{sid}/label-map",
                     params={"file": '{"format": "LABEL_MAP_FORMAT_NIFTI"}'}, data=bad.read_bytes(),
                     timeout=30)
    assert r.status_code == 400
    page.locator(".intake input[type=file]").set_input_files(str(bad))
    page.get_by_role("button", name="Upload").click()
    said = page.locator(".intake .upload .say.error")
    said.wait_for()
    assert said.inner_text() == f"Upload refused: {r.json()['detail']}"
    assert session(server, sid)["state"] == "SESSION_STATE_EMPTY"
    page.close()


def test_the_upload_asks_for_the_token_as_the_other_calls_do(browser, phantom_file):
    token = "intake-test-token-0123456789"
    server = Server("--token", token)
    try:
        auth = {"authorization": f"Bearer {token}"}
        sid = requests.post(f"{server.http_url}/v1/sessions", json={"displayName": "token"},
                            headers=auth, timeout=30).json()["session"]["id"]
        page = browser.new_page()
        page.goto(f"{server.bound['page']}?session={sid}")

        def give_token():
            page.locator(".modal input[type=password]").fill(token)
            page.get_by_role("button", name="Connect").click()

        give_token()  # the watch stream's 401
        page.locator(".intake form.upload").wait_for()
        # The token forgotten: the upload's 401 asks for it again, and the upload goes through.
        page.evaluate("sessionStorage.clear()")
        page.locator(".intake input[type=file]").set_input_files(str(phantom_file))
        page.get_by_role("button", name="Upload").click()
        give_token()
        page.locator(".intake .summary tbody tr").first.wait_for()
        assert page.evaluate("sessionStorage.getItem('resecta.token')") == token
        r = requests.get(f"{server.http_url}/v1/sessions/{sid}", headers=auth, timeout=30)
        assert r.json()["session"]["state"] == "SESSION_STATE_LABEL_MAP"
        page.close()
    finally:
        server.stop()
