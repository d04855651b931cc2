"""Checks of deploy/kubernetes/ that kubernetes-validate cannot make (run by validate.sh).

  python3 validate_crds.py --kubernetes-version 1.33.0 --crds schemas/ FILE...

1. Objects of a custom resource (KEDA's ScaledObject, TriggerAuthentication) are validated
   against the openAPIV3Schema of their CRD, vendored in schemas/ (schemas/README.md), and their
   metadata against Kubernetes' ObjectMeta (the schemas kubernetes-validate bundles). The API
   server prunes fields a CRD does not declare (it rejects them only when the client asks for
   strict field validation), so a misspelt field could be lost without an error; here every
   object schema that lists its `properties` gets `additionalProperties: false` unless the CRD
   sets `x-kubernetes-preserve-unknown-fields`, and a misspelt field fails. (The CRD's CEL rules,
   `x-kubernetes-validations`, are not evaluated; jsonschema ignores `x-kubernetes-*` keywords.)
   A trigger's `metadata`, a free string map in the CRD, is checked against the names its
   scaler reads (TRIGGER_METADATA).
2. The references between the files (every FILE is read, custom resource or not): autoscaler
   targets name a Deployment here, a trigger's authenticationRef names a TriggerAuthentication,
   every Secret key a container or TriggerAuthentication reads is in the Secret template, a
   Deployment's selector matches its pod labels and its containers share one image, and every
   object is in the Namespace defined here.
   A wrong name there is valid YAML of a valid schema and fails only in the cluster.

Exits 1 with one line per problem, 0 when every check passes.
"""

import argparse
import copy
import pathlib
import sys

import jsonschema
import referencing
import yaml
from kubernetes_validate import utils as kv_utils


# A trigger's `metadata` is a free string map in the CRD; KEDA reads the names its scaler knows and
# ignores the rest, so a misspelt name would only fail (or silently change nothing) in the cluster.
# The names each scaler reads, from its source at the vendored release (v2.20.2,
# pkg/scalers/postgresql_scaler.go: fields read from triggerMetadata, and `...FromEnv` for those
# read from resolvedEnv): (required, allowed). TRIGGER_AUTH_PARAMS: the parameters the scaler
# reads from authParams, i.e. what a TriggerAuthentication it uses may set.
TRIGGER_METADATA = {
    "postgresql": (
        {"query", "targetQueryValue"},
        {"query", "targetQueryValue", "activationTargetQueryValue", "host", "port", "userName",
         "dbName", "sslmode", "connectionFromEnv", "passwordFromEnv"},
    ),
}
TRIGGER_AUTH_PARAMS = {
    "postgresql": {"connection", "host", "port", "userName", "dbName", "sslmode", "password"},
}


def strict(schema):
    """`schema` with `additionalProperties: false` on every object schema that lists properties."""
    schema = copy.deepcopy(schema)

    def walk(node):
        if isinstance(node, dict):
            if (
                "properties" in node
                and "additionalProperties" not in node
                and not node.get("x-kubernetes-preserve-unknown-fields")
            ):
                node["additionalProperties"] = False
            for value in node.values():
                walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    walk(schema)
    return schema


def load_crds(folder):
    """{(apiVersion, kind): strict schema} for every served version of every CRD in `folder`."""
    schemas = {}
    for path in sorted(pathlib.Path(folder).glob("*.yaml")):
        crd = yaml.safe_load(path.read_text())
        if crd.get("kind") != "CustomResourceDefinition":
            continue
        group, kind = crd["spec"]["group"], crd["spec"]["names"]["kind"]
        for version in crd["spec"]["versions"]:
            if version.get("served"):
                schema = strict(version["schema"]["openAPIV3Schema"])
                # CRD schemas are OpenAPI 3.0, whose keywords (boolean exclusiveMinimum, ...)
                # are those of JSON Schema draft 4.
                jsonschema.Draft4Validator.check_schema(schema)
                schemas[(f"{group}/{version['name']}", kind)] = schema
    if not schemas:
        sys.exit(f"validate_crds: no CustomResourceDefinition in {folder}")
    return schemas


def object_meta_validator(kubernetes_version):
    """A validator of ObjectMeta from kubernetes-validate's strict schemas of that version."""
    major_minor = ".".join(kubernetes_version.lstrip("v").split(".")[:2])
    version = [v for v in kv_utils.all_versions() if kv_utils.major_minor(v) == major_minor]
    if not version:
        sys.exit(f"validate_crds: kubernetes-validate has no schemas for {kubernetes_version}")
    definitions = kv_utils.schema_contents(
        f"kubernetes-json-schema/v{version[-1]}-local-strict/_definitions.json", kubernetes_version
    )
    registry = referencing.Registry().with_resource(
        definitions["$id"], referencing.Resource.from_contents(definitions)
    )
    ref = {"$ref": definitions["$id"] + "#/$defs/io.k8s.apimachinery.pkg.apis.meta.v1.ObjectMeta"}
    return jsonschema.Draft202012Validator(ref, registry=registry)


def errors_of(validator, instance, where, prefix=()):
    for error in sorted(validator.iter_errors(instance), key=lambda e: list(e.absolute_path)):
        path = ".".join(str(p) for p in (*prefix, *error.absolute_path)) or "(top)"
        yield f"{where}: {path}: {error.message}"


def check_custom_resources(objects, crds, meta_validator):
    for where, obj in objects:
        key = (obj.get("apiVersion"), obj.get("kind"))
        if key not in crds:
            continue
        yield from errors_of(jsonschema.Draft4Validator(crds[key]), obj, where)
        yield from errors_of(meta_validator, obj.get("metadata", {}), where, ("metadata",))
        for i, trigger in enumerate(obj.get("spec", {}).get("triggers", [])):
            if trigger.get("type") not in TRIGGER_METADATA:
                yield f"{where}: spec.triggers.{i}: no list of metadata names for trigger type {trigger.get('type')!r} (add it to TRIGGER_METADATA)"
                continue
            required, allowed = TRIGGER_METADATA[trigger["type"]]
            names = set(trigger.get("metadata", {}))
            for name in sorted(required - names):
                yield f"{where}: spec.triggers.{i}.metadata: {name!r} is required by the {trigger['type']} scaler"
            for name in sorted(names - allowed):
                yield f"{where}: spec.triggers.{i}.metadata: {name!r} is not read by the {trigger['type']} scaler"


def check_references(objects):
    by_kind = {}
    for where, obj in objects:
        by_kind.setdefault(obj.get("kind"), {})[obj.get("metadata", {}).get("name")] = obj
    namespaces = set(by_kind.get("Namespace", {}))
    secrets = {
        name: set(s.get("stringData", {})) | set(s.get("data", {}))
        for name, s in by_kind.get("Secret", {}).items()
    }

    def secret_key(where, name, key):
        if name not in secrets:
            yield f"{where}: Secret {name!r} is not defined here"
        elif key not in secrets[name]:
            yield f"{where}: Secret {name!r} has no key {key!r}"

    for where, obj in objects:
        kind, meta, spec = obj.get("kind"), obj.get("metadata", {}), obj.get("spec", {})
        if kind != "Namespace" and meta.get("namespace") not in namespaces:
            yield f"{where}: namespace {meta.get('namespace')!r} is not a Namespace defined here"
        if kind in ("ScaledObject", "HorizontalPodAutoscaler"):
            target = spec.get("scaleTargetRef", {})
            if target.get("kind", "Deployment") != "Deployment" or target.get("name") not in by_kind.get("Deployment", {}):
                yield f"{where}: scaleTargetRef {target} is not a Deployment defined here"
        for trigger in spec.get("triggers", []) if kind == "ScaledObject" else []:
            auth = trigger.get("authenticationRef", {}).get("name")
            if auth is None:
                continue
            if auth not in by_kind.get("TriggerAuthentication", {}):
                yield f"{where}: authenticationRef {auth!r} is not a TriggerAuthentication defined here"
                continue
            allowed = TRIGGER_AUTH_PARAMS.get(trigger.get("type"), set())
            for ref in by_kind["TriggerAuthentication"][auth].get("spec", {}).get("secretTargetRef", []):
                if ref.get("parameter") not in allowed:
                    yield f"{where}: TriggerAuthentication {auth!r} sets {ref.get('parameter')!r}, which the {trigger.get('type')} scaler does not read"
        if kind == "TriggerAuthentication":
            for ref in spec.get("secretTargetRef", []):
                yield from secret_key(where, ref.get("name"), ref.get("key"))
        if kind == "Deployment":
            pod = spec.get("template", {})
            labels = pod.get("metadata", {}).get("labels", {})
            selector = spec.get("selector", {}).get("matchLabels", {})
            if not selector or any(labels.get(k) != v for k, v in selector.items()):
                yield f"{where}: selector {selector} does not match the pod labels {labels}"
            pod_spec = pod.get("spec", {})
            containers = pod_spec.get("initContainers", []) + pod_spec.get("containers", [])
            # The init container copies the image's assets for the main container, so both must
            # be the same image (a tag bumped in one place only would mix two versions).
            images = {c.get("image") for c in containers}
            if len(images) != 1:
                yield f"{where}: its containers use different images {sorted(map(str, images))}"
            for container in containers:
                for env in container.get("env", []):
                    ref = env.get("valueFrom", {}).get("secretKeyRef")
                    if ref:
                        yield from secret_key(f"{where}: {container['name']}", ref.get("name"), ref.get("key"))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kubernetes-version", required=True)
    parser.add_argument("--crds", required=True, help="folder of CustomResourceDefinition YAML files")
    parser.add_argument("files", nargs="+")
    args = parser.parse_args()

    crds = load_crds(args.crds)
    objects = []
    for path in args.files:
        with open(path) as f:
            for doc in yaml.safe_load_all(f):
                if doc:
                    objects.append((f"{path} ({doc.get('kind')}/{doc.get('metadata', {}).get('name')})", doc))
    custom = [where for where, o in objects if (o.get("apiVersion"), o.get("kind")) in crds]
    # An object of a vendored CRD's group but of an unknown version or kind (a typo) would
    # otherwise pass unchecked; objects of other groups are kubernetes-validate's.
    groups = {api_version.split("/")[0] for api_version, _ in crds}
    problems = [
        f"{where}: {o.get('apiVersion')} {o.get('kind')} is no kind of the vendored CRDs"
        for where, o in objects
        if str(o.get("apiVersion")).split("/")[0] in groups
        and (o.get("apiVersion"), o.get("kind")) not in crds
    ]
    problems += check_custom_resources(objects, crds, object_meta_validator(args.kubernetes_version))
    problems += check_references(objects)
    if not custom:
        problems.append("no custom resource among the files: nothing was checked against a CRD")
    for problem in problems:
        print(f"ERROR {problem}")
    if problems:
        return 1
    for where in custom:
        print(f"INFO {where} passed against its CRD (strict)")
    print(f"INFO references between the {len(objects)} objects passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
