"""Keeps deploy/kubernetes and docker/compose.yaml correct without a cluster or a Docker engine.

The kustomize base and its overlays are rendered here (a small resolver of what the files use:
`resources`, `namespace`, `images`, strategic-merge `patches`), every rendered document is
validated against the Kubernetes JSON schema of KUBERNETES_VERSION (kubernetes-validate, its
schemas bundled: no network; strict, so an unknown field fails), and the project's own rules are
checked: probes, ports, secrets, resources, the GPU and trial overlays. The compose file is
validated against the compose-spec schema that check-jsonschema bundles.
"""

import copy
import importlib.resources
import json
import re
import subprocess
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import jsonschema
import kubernetes_validate
import pytest
import yaml
from conftest import resecta_bin

ROOT = Path(__file__).resolve().parent.parent
KUBE = ROOT / "deploy" / "kubernetes"
COMPOSE = ROOT / "docker" / "compose.yaml"
KUBERNETES_VERSION = "1.30"
TARGETS = ["base", "overlays/gpu", "overlays/trial"]
PLACEHOLDER = "CHANGE-ME"
# What `resecta serve` does on SIGTERM before it exits: calls in flight get up to 5 s
# (docs/server.md, Shutdown); leases are released at once.
DRAIN_S = 5
# The kustomization fields this resolver understands; anything else would be silently ignored.
KUSTOMIZE_FIELDS = {"apiVersion", "kind", "namespace", "resources", "images", "patches"}
# The variables the replicated server reads (besides those `resecta serve --help` lists today).
REPLICA_ENV = {
    "RESECTA_STORE",
    "RESECTA_STORE_PASSWORD_FILE",
    "RESECTA_REPLICA_ID",
    "RESECTA_ADVERTISE_GRPC",
    "RESECTA_ADVERTISE_HTTP",
    "RESECTA_LEASE_MS",
}


# --- a small kustomize ---------------------------------------------------------------------


def load_all(path):
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def merge(base, patch):
    """Strategic merge as Kubernetes does it for the fields these manifests patch: maps merge
    recursively, lists of named maps (containers, env, volumes, mounts) merge by name, other
    lists are replaced."""
    if isinstance(base, dict) and isinstance(patch, dict):
        out = dict(base)
        for k, v in patch.items():
            out[k] = merge(base[k], v) if k in base else copy.deepcopy(v)
        return out
    named = lambda xs: isinstance(xs, list) and all(isinstance(x, dict) and "name" in x for x in xs)
    if named(base) and named(patch) and patch:
        out = [copy.deepcopy(x) for x in base]
        for p in patch:
            i = next((i for i, x in enumerate(out) if x["name"] == p["name"]), None)
            if i is None:
                out.append(copy.deepcopy(p))
            else:
                out[i] = merge(out[i], p)
        return out
    return copy.deepcopy(patch)


def split_image(image):
    name, sep, tag = image.rpartition(":")
    if not sep or "/" in tag:
        return image, None
    return name, tag


def set_images(doc, images):
    spec = doc.get("spec", {}).get("template", {}).get("spec", {})
    for c in spec.get("containers", []) + spec.get("initContainers", []):
        name, tag = split_image(c["image"])
        for rule in images:
            if rule["name"] == name:
                name = rule.get("newName", name)
                tag = rule.get("newTag", tag)
                c["image"] = f"{name}:{tag}" if tag else name


def render(target):
    """The documents `kubectl kustomize deploy/kubernetes/<target>` prints."""
    directory = KUBE / target
    k = yaml.safe_load((directory / "kustomization.yaml").read_text())
    assert k["apiVersion"] == "kustomize.config.k8s.io/v1beta1" and k["kind"] == "Kustomization"
    unknown = set(k) - KUSTOMIZE_FIELDS
    assert not unknown, f"{target}: kustomization fields {unknown} are not rendered by this test"
    docs = []
    for r in k.get("resources", []):
        path = (directory / r).resolve()
        docs += render(path.relative_to(KUBE)) if path.is_dir() else load_all(path)
    for p in k.get("patches", []):
        assert set(p) == {"path"}, f"{target}: only file patches are rendered: {p}"
        for patch in load_all(directory / p["path"]):
            key = (patch["kind"], patch["metadata"]["name"])
            hits = [i for i, d in enumerate(docs) if (d["kind"], d["metadata"]["name"]) == key]
            assert len(hits) == 1, f"{target}: patch {p['path']} matches {len(hits)} resources"
            docs[hits[0]] = merge(docs[hits[0]], patch)
    for d in docs:
        set_images(d, k.get("images", []))
        if "namespace" in k and d["kind"] != "Namespace":
            d["metadata"]["namespace"] = k["namespace"]
    return docs


@pytest.fixture(scope="module", params=TARGETS)
def rendered(request):
    return request.param, render(request.param)


def find(docs, kind, name=None):
    hits = [d for d in docs if d["kind"] == kind and (name is None or d["metadata"]["name"] == name)]
    assert hits, f"no {kind} {name or ''}"
    return hits


def server(docs):
    """The resecta Deployment's pod spec and its container."""
    pod = find(docs, "Deployment", "resecta")[0]["spec"]["template"]["spec"]
    return pod, next(c for c in pod["containers"] if c["name"] == "resecta")


def env_of(container):
    return {e["name"]: e for e in container.get("env", [])}


def all_containers(docs):
    for d in docs:
        spec = d.get("spec", {}).get("template", {}).get("spec")
        if spec:
            for c in spec.get("initContainers", []) + spec["containers"]:
                yield d, spec, c


# --- Kubernetes schema ---------------------------------------------------------------------


def test_every_document_validates_against_the_kubernetes_schema(rendered):
    target, docs = rendered
    assert docs
    for d in docs:
        try:
            version = kubernetes_validate.validate(d, KUBERNETES_VERSION, strict=True)
        except kubernetes_validate.ValidationError as e:
            path = ".".join(str(p) for p in e.path)
            pytest.fail(f"{target}: {d['kind']}/{d['metadata']['name']}: {path}: {e.message}")
        except kubernetes_validate.SchemaNotFoundError as e:
            pytest.fail(f"{target}: {e.message}")
        assert version == KUBERNETES_VERSION


def test_a_broken_manifest_fails_the_schema():
    """The validator is strict: a misspelt field and a wrong type are caught."""
    deployment = copy.deepcopy(find(render("base"), "Deployment", "resecta")[0])
    deployment["spec"]["template"]["spec"]["containers"][0]["readinessprobe"] = {}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(deployment, KUBERNETES_VERSION, strict=True)
    deployment = copy.deepcopy(find(render("base"), "Deployment", "resecta")[0])
    deployment["spec"]["replicas"] = "two"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(deployment, KUBERNETES_VERSION, strict=True)


def test_names_are_unique_and_namespaced(rendered):
    target, docs = rendered
    keys = [(d["kind"], d["metadata"]["name"]) for d in docs]
    assert len(keys) == len(set(keys)), f"{target}: duplicate resources"
    assert find(docs, "Namespace", "resecta")
    for d in docs:
        if d["kind"] != "Namespace":
            assert d["metadata"].get("namespace") == "resecta", f"{target}: {d['kind']} {d['metadata']['name']} has no namespace"


# --- the planning server -------------------------------------------------------------------


def test_probes_use_healthz_and_readyz(rendered):
    _, docs = rendered
    _, c = server(docs)
    ports = {p["name"]: p["containerPort"] for p in c["ports"]}
    for probe, path in [("startupProbe", "/healthz"), ("livenessProbe", "/healthz"), ("readinessProbe", "/readyz")]:
        get = c[probe]["httpGet"]
        assert get["path"] == path, f"{probe} reads {get['path']}"
        assert get["port"] == "http" and ports["http"] == 8080
        assert get.get("scheme", "HTTP") == "HTTP"
    # Liveness must not restart a replica for what readiness reports (the store, draining).
    assert c["livenessProbe"]["httpGet"]["path"] != "/readyz"


def test_ports_listen_addresses_and_service_agree(rendered):
    _, docs = rendered
    pod, c = server(docs)
    env = env_of(c)
    ports = {p["name"]: p["containerPort"] for p in c["ports"]}
    assert ports == {"grpc": 50051, "http": 8080}
    assert env["RESECTA_GRPC"]["value"] == "0.0.0.0:50051"
    assert env["RESECTA_HTTP"]["value"] == "0.0.0.0:8080"
    svc = find(docs, "Service", "resecta")[0]["spec"]
    assert svc["type"] == "ClusterIP"
    by_name = {p["name"]: p for p in svc["ports"]}
    assert set(by_name) == {"grpc", "http"}
    assert by_name["grpc"]["appProtocol"] == "kubernetes.io/h2c"
    assert by_name["http"]["appProtocol"] == "http"
    for name, p in by_name.items():
        assert p["targetPort"] == name and p["port"] == ports[name]
    labels = find(docs, "Deployment", "resecta")[0]["spec"]["template"]["metadata"]["labels"]
    assert svc["selector"].items() <= labels.items()


def test_replicas_spread_and_survive_disruptions(rendered):
    _, docs = rendered
    deployment = find(docs, "Deployment", "resecta")[0]["spec"]
    assert deployment["replicas"] >= 2
    assert deployment["strategy"]["rollingUpdate"]["maxUnavailable"] == 0
    labels = deployment["template"]["metadata"]["labels"]
    assert deployment["selector"]["matchLabels"].items() <= labels.items()
    terms = deployment["template"]["spec"]["affinity"]["podAntiAffinity"][
        "preferredDuringSchedulingIgnoredDuringExecution"
    ]
    assert any(
        t["podAffinityTerm"]["topologyKey"] == "kubernetes.io/hostname"
        and t["podAffinityTerm"]["labelSelector"]["matchLabels"].items() <= labels.items()
        for t in terms
    )
    pdb = find(docs, "PodDisruptionBudget", "resecta")[0]["spec"]
    assert pdb["minAvailable"] == 1
    assert pdb["selector"]["matchLabels"].items() <= labels.items()


def test_grace_period_covers_the_drain(rendered):
    _, docs = rendered
    pod, c = server(docs)
    pre_stop = c["lifecycle"]["preStop"]["exec"]["command"]
    assert pre_stop[0] == "sleep"
    lease_s = int(env_of(c)["RESECTA_LEASE_MS"]["value"]) / 1000
    needed = int(pre_stop[1]) + DRAIN_S + lease_s
    assert pod["terminationGracePeriodSeconds"] > needed


def test_replica_identity_comes_from_the_downward_api(rendered):
    _, docs = rendered
    _, c = server(docs)
    env = env_of(c)
    assert env["POD_IP"]["valueFrom"]["fieldRef"]["fieldPath"] == "status.podIP"
    assert env["POD_NAME"]["valueFrom"]["fieldRef"]["fieldPath"] == "metadata.name"
    names = list(env)
    for var in ["RESECTA_ADVERTISE_GRPC", "RESECTA_ADVERTISE_HTTP", "RESECTA_REPLICA_ID"]:
        # $(VAR) expands only variables defined earlier in the list.
        for ref in re.findall(r"\$\((\w+)\)", env[var]["value"]):
            assert names.index(ref) < names.index(var), f"{var} uses {ref} before it is defined"
    assert env["RESECTA_ADVERTISE_GRPC"]["value"] == "$(POD_IP):50051"
    assert env["RESECTA_ADVERTISE_HTTP"]["value"] == "http://$(POD_IP):8080"
    assert env["RESECTA_REPLICA_ID"]["value"] == "$(POD_NAME)"
    assert int(env["RESECTA_LEASE_MS"]["value"]) > 0


def mounted_secret_file(pod, container, path):
    """(secret name, key) behind a file path in the container, or None."""
    volumes = {v["name"]: v for v in pod["volumes"]}
    for m in container["volumeMounts"]:
        prefix = m["mountPath"].rstrip("/") + "/"
        if path.startswith(prefix) and "secret" in volumes[m["name"]]:
            secret = volumes[m["name"]]["secret"]
            rel = path[len(prefix) :]
            for item in secret.get("items", []):
                if item["path"] == rel:
                    return secret["secretName"], item["key"]
            return secret["secretName"], rel
    return None


def test_token_and_store_credentials_come_from_secrets(rendered):
    _, docs = rendered
    pod, c = server(docs)
    env = env_of(c)
    secrets = {s["metadata"]["name"]: s for s in find(docs, "Secret")}
    assert "RESECTA_TOKEN" not in env and "RESECTA_STORE_PASSWORD" not in env
    for var in ["RESECTA_TOKEN_FILE", "RESECTA_STORE_PASSWORD_FILE"]:
        where = mounted_secret_file(pod, c, env[var]["value"])
        assert where, f"{var} is not a file of a mounted Secret"
        name, key = where
        assert key in secrets[name]["stringData"], f"{var}: Secret {name} has no key {key}"
    ref = env["RESECTA_STORE"]["valueFrom"]["secretKeyRef"]
    url = secrets[ref["name"]]["stringData"][ref["key"]]
    parts = urlsplit(url)
    assert parts.scheme == "postgres" and parts.username and parts.password is None, url
    assert parts.port == 5432
    # The CA the URL names is mounted.
    root_cert = parse_qs(parts.query).get("sslrootcert")
    if root_cert:
        mounts = [m["mountPath"].rstrip("/") + "/" for m in c["volumeMounts"]]
        assert any(root_cert[0].startswith(m) for m in mounts), root_cert


def test_secrets_hold_placeholders_only(rendered):
    target, docs = rendered
    for s in find(docs, "Secret"):
        assert "data" not in s, f"{target}: Secret {s['metadata']['name']} carries encoded data"
        for key, value in s["stringData"].items():
            if key == "url":
                assert urlsplit(value).password is None, f"{target}: a password in the URL"
            else:
                assert value == PLACEHOLDER, f"{target}: Secret {s['metadata']['name']}.{key} is not {PLACEHOLDER}"


def test_every_container_has_requests_limits_and_a_pinned_image(rendered):
    target, docs = rendered
    for d, _, c in all_containers(docs):
        res = c["resources"]
        for kind in ["requests", "limits"]:
            assert {"cpu", "memory"} <= set(res[kind]), f"{target}: {c['name']} {kind}"
        name, tag = split_image(c["image"])
        assert tag and tag != "latest", f"{target}: {c['name']} image {c['image']}"
        assert c["imagePullPolicy"] == "IfNotPresent"


def gib(quantity):
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
    number, unit = re.fullmatch(r"(\d+)([KMGT]i)", quantity).groups()
    return int(number) * units[unit] / 2**30


def test_memory_budget_fits_the_limit(rendered):
    _, docs = rendered
    pod, c = server(docs)
    assert c["resources"]["requests"]["memory"] and gib(c["resources"]["limits"]["memory"]) >= 2
    config = env_of(c)["RESECTA_CONFIG"]["value"]
    mount = next(m for m in c["volumeMounts"] if config.startswith(m["mountPath"] + "/"))
    volume = next(v for v in pod["volumes"] if v["name"] == mount["name"])
    cm = find(docs, "ConfigMap", volume["configMap"]["name"])[0]
    toml_text = cm["data"][config[len(mount["mountPath"]) + 1 :]]
    budget = int(re.search(r"^max_memory_bytes\s*=\s*(\d+)", toml_text, re.M)[1])
    # Room for the runtime, allocator slack and what the budget does not charge.
    assert budget / 2**30 <= 0.8 * gib(c["resources"]["limits"]["memory"])


def test_pods_run_restricted(rendered):
    target, docs = rendered
    for d, pod, c in all_containers(docs):
        ps = pod["securityContext"]
        assert ps["runAsNonRoot"] is True and ps["runAsUser"] > 0
        assert ps["seccompProfile"]["type"] == "RuntimeDefault"
        assert pod["automountServiceAccountToken"] is False
        sc = c["securityContext"]
        assert sc["readOnlyRootFilesystem"] is True and sc["allowPrivilegeEscalation"] is False
        assert sc["capabilities"]["drop"] == ["ALL"]
        volumes = {v["name"]: v for v in pod["volumes"]}
        tmp = [m for m in c["volumeMounts"] if m["mountPath"] == "/tmp"]
        assert tmp and "emptyDir" in volumes[tmp[0]["name"]], f"{target}: {c['name']} has no /tmp"
    pod, _ = server(docs)
    assert pod["securityContext"]["runAsUser"] == 10001  # docker/Dockerfile's resecta user


def test_base_plans_on_the_cpu():
    docs = render("base")
    pod, c = server(docs)
    assert c["image"] == "resecta:cpu"
    assert "nvidia.com/gpu" not in c["resources"]["limits"]
    assert "RESECTA_GPU" not in env_of(c) and "nodeSelector" not in pod
    assert not [d for d in docs if d["kind"] == "StatefulSet"], "the base's PostgreSQL is external"


def test_gpu_overlay_requests_a_gpu():
    pod, c = server(render("overlays/gpu"))
    assert c["image"] == "resecta:gpu"
    assert c["resources"]["limits"]["nvidia.com/gpu"] == 1
    assert pod["nodeSelector"]["nvidia.com/gpu.present"] == "true"
    assert any(t["key"] == "nvidia.com/gpu" and t["effect"] == "NoSchedule" for t in pod["tolerations"])
    env = env_of(c)
    assert env["RESECTA_GPU"]["value"] == "required"
    # The patch adds to the base's container; it does not replace it.
    assert env["RESECTA_STORE"] and c["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert c["resources"]["limits"]["memory"] == server(render("base"))[1]["resources"]["limits"]["memory"]


def test_trial_overlay_runs_its_own_postgres():
    docs = render("overlays/trial")
    pod, c = server(docs)
    sts = find(docs, "StatefulSet", "resecta-postgres")[0]
    assert sts["spec"]["replicas"] == 1
    pg = sts["spec"]["template"]["spec"]["containers"][0]
    assert pg["image"] == "postgres:15"
    claims = {t["metadata"]["name"] for t in sts["spec"]["volumeClaimTemplates"]}
    data_mount = next(m for m in pg["volumeMounts"] if m["mountPath"] == "/var/lib/postgresql/data")
    assert data_mount["name"] in claims
    for probe in ["livenessProbe", "readinessProbe", "startupProbe"]:
        assert pg[probe]["exec"]["command"][0] == "pg_isready"
    svc = find(docs, "Service", sts["spec"]["serviceName"])[0]["spec"]
    assert svc["selector"].items() <= sts["spec"]["template"]["metadata"]["labels"].items()
    # The server's URL names that Service, its port and the role and database PostgreSQL creates.
    ref = env_of(c)["RESECTA_STORE"]["valueFrom"]["secretKeyRef"]
    url = urlsplit(find(docs, "Secret", ref["name"])[0]["stringData"][ref["key"]])
    pg_env = env_of(pg)
    assert (url.hostname, url.port) == (sts["spec"]["serviceName"], svc["ports"][0]["port"])
    assert url.username == pg_env["POSTGRES_USER"]["value"]
    assert url.path == "/" + pg_env["POSTGRES_DB"]["value"]
    # One password for both sides.
    pg_password = mounted_secret_file(sts["spec"]["template"]["spec"], pg, pg_env["POSTGRES_PASSWORD_FILE"]["value"])
    server_password = mounted_secret_file(pod, c, env_of(c)["RESECTA_STORE_PASSWORD_FILE"]["value"])
    assert pg_password == server_password


def test_env_names_are_ones_resecta_serve_reads():
    """Every RESECTA_* variable the manifests and the compose file set is read by `resecta
    serve` (needs the built binary, as tests/test_docker.py)."""
    names = set()
    for target in TARGETS:
        for _, _, c in all_containers(render(target)):
            names |= {n for n in env_of(c) if n.startswith("RESECTA_")}
    for svc in yaml.safe_load(COMPOSE.read_text())["services"].values():
        names |= {n for n in svc.get("environment", {}) if n.startswith("RESECTA_")}
    assert REPLICA_ENV <= names
    binary = Path(resecta_bin())
    if not binary.exists():
        pytest.skip(f"{binary} is not built")
    done = subprocess.run([str(binary), "serve", "--help"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    # `[env: NAME=]`, or `[env: NAME]` for those whose values help never shows (secrets).
    missing = sorted(n for n in names if not re.search(rf"env: {n}[=\]]", done.stdout))
    assert not missing, f"`resecta serve` reads none of {missing}"


# --- docker/compose.yaml -------------------------------------------------------------------


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load(COMPOSE.read_text())


def test_compose_validates_against_the_compose_spec(compose):
    schema_file = importlib.resources.files("check_jsonschema.builtin_schemas.vendor") / "compose-spec.json"
    schema = json.loads(schema_file.read_text())
    validator = jsonschema.validators.validator_for(schema)(schema)
    errors = [f"{'.'.join(map(str, e.path))}: {e.message}" for e in validator.iter_errors(compose)]
    assert not errors, errors
    broken = copy.deepcopy(compose)
    broken["services"]["resecta"]["depends_on"] = {"postgres": {"condition": "when-ready"}}
    assert list(validator.iter_errors(broken)), "the schema should refuse an unknown condition"


def test_compose_keeps_the_single_server(compose):
    services = compose["services"]
    assert "profiles" not in services["resecta"]
    assert services["resecta"]["environment"]["RESECTA_TOKEN_FILE"] == "/run/secrets/resecta_token"
    assert "RESECTA_STORE" not in services["resecta"]["environment"]
    assert services["resecta-gpu"]["profiles"] == ["gpu"]


def test_compose_replicas_profile(compose):
    services = compose["services"]
    replicas = {n: s for n, s in services.items() if "replicas" in s.get("profiles", [])}
    assert {"postgres", "resecta-a", "resecta-b"} <= set(replicas)
    pg = services["postgres"]
    assert pg["image"] == "postgres:15"
    assert "pg_isready" in " ".join(pg["healthcheck"]["test"])
    assert pg["environment"]["POSTGRES_PASSWORD_FILE"] == "/run/secrets/resecta_store_password"
    assert "resecta_store_password" in pg["secrets"]
    assert any(v.split(":")[1] == "/var/lib/postgresql/data" for v in pg["volumes"])
    host_ports = []
    for name in ["resecta-a", "resecta-b"]:
        svc = services[name]
        env = svc["environment"]
        assert svc["image"] == "resecta:cpu"
        assert svc["depends_on"]["postgres"]["condition"] == "service_healthy"
        url = urlsplit(env["RESECTA_STORE"])
        assert (url.scheme, url.username, url.hostname, url.port, url.path) == (
            "postgres", pg["environment"]["POSTGRES_USER"], "postgres", 5432, "/" + pg["environment"]["POSTGRES_DB"]
        )
        assert url.password is None
        for s in ["resecta_token", "resecta_store_password"]:
            assert s in svc["secrets"] and s in compose["secrets"]
        assert env["RESECTA_TOKEN_FILE"] == "/run/secrets/resecta_token"
        assert env["RESECTA_STORE_PASSWORD_FILE"] == "/run/secrets/resecta_store_password"
        grpc_port = int(env["RESECTA_GRPC"].rsplit(":", 1)[1])
        http_port = int(env["RESECTA_HTTP"].rsplit(":", 1)[1])
        # Each replica advertises the address its published port is reached at.
        assert env["RESECTA_ADVERTISE_GRPC"].endswith(f":{grpc_port}")
        assert env["RESECTA_ADVERTISE_HTTP"].endswith(f":{http_port}")
        assert env["RESECTA_REPLICA_ID"] == name
        assert sorted(svc["ports"]) == sorted([f"{grpc_port}:{grpc_port}", f"{http_port}:{http_port}"])
        assert f"127.0.0.1:{http_port}/readyz" in " ".join(svc["healthcheck"]["test"])
        host_ports += [grpc_port, http_port]
    assert sorted(host_ports) == [8080, 8081, 50051, 50052]
    assert len(set(host_ports)) == 4


# --- docs ----------------------------------------------------------------------------------


def test_deployment_guide_links_what_exists():
    text = (ROOT / "docs" / "deployment.md").read_text()
    assert "## Measured" in text
    for link in re.findall(r"\]\(([^)#\s]+)", text):
        if "://" not in link:
            assert (ROOT / "docs" / link).resolve().exists(), f"docs/deployment.md links {link}"
    assert "docs/deployment.md" in (ROOT / "README.md").read_text()
