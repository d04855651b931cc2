"""A real LTI 1.3 platform on loopback for the server's LTI tests (server/tests/lti_flow.rs).

The platform side of every message is the `lti1p3platform` package (MIT): its registration and
key set, the OIDC launch (id_token signing), the Deep Linking claim and response validation, the
OAuth 2 token endpoint (client_credentials with the tool's signed JWT assertion, verified against
the tool's JWKS fetched over HTTP), and the AGS and NRPS services (bearer token checks). This file
only adds a standard-library HTTP server, an in-memory store, and test hooks:

  GET  /start?message=resource|deeplink&user=SUB&role=learner|instructor&link=ID&tamper=KIND
       -> 302 to the tool's OIDC login (third-party initiated), lti_message_hint names the launch
  GET  /auth                 OIDC authentication endpoint -> auto-post form to the tool's launch
  GET  /jwks                 the platform's key set
  POST /token                OAuth 2 token endpoint
  POST /deep-link-return     Deep Linking return: validates the tool's JWT, creates line items
  GET/POST /ags/lineitems..., POST .../scores, GET .../results     AGS
  GET  /nrps/memberships     NRPS (2 members per page, Link rel=next)
  GET  /debug/scores         every score received, in order (test read-back)

Usage: platform.py TOOL_URL   (prints {"port": N, "issuer": ...} on its first line)
"""

import os
import sys

# This file's name shadows the standard library's `platform` (which `uuid` imports): drop the
# script's own folder from the import path before anything else is imported.
sys.path = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import json  # noqa: E402
import threading
import uuid
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qsl, urlencode, urlparse

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import rsa

from lti1p3platform.ltiplatform import LTI1P3PlatformConfAbstract
from lti1p3platform.registration import Registration
from lti1p3platform.message_launch import LTIAdvantageMessageLaunchAbstract
from lti1p3platform.request import Request
from lti1p3platform.service_connector import (
    AssignmentsGradesService,
    NamesRoleProvisioningService,
)
from lti1p3platform.membership import Context
from lti1p3platform.score import UpdateScoreStatus
from lti1p3platform.exceptions import LineItemNotFoundException

CLIENT_ID = "painsim-tool"
DEPLOYMENT_ID = "deployment-1"
CONTEXT = {"id": "course-42", "title": "Interventional pain, spring", "label": "PAIN-101"}
ROLES = {
    "learner": ["http://purl.imsglobal.org/vocab/lis/v2/membership#Learner"],
    "instructor": ["http://purl.imsglobal.org/vocab/lis/v2/membership#Instructor"],
}

LOCK = threading.Lock()
STORE = {
    "launches": {},  # message hint -> launch settings
    "links": {},  # resource link id -> {"custom": ..., "lineitem": id, "title": ...}
    "lineitems": {},  # id -> line item
    "scores": [],  # every score received: {"lineitem": id, "score": {...}}
    "deep_link_items": [],
}
MEMBERS = [
    {"user_id": "learner-1", "name": "Ada Learner", "roles": ROLES["learner"]},
    {"user_id": "learner-2", "name": "Ben Learner", "roles": ROLES["learner"]},
    {"user_id": "teacher-1", "name": "Cy Teacher", "roles": ROLES["instructor"]},
    {"user_id": "gone-1", "name": "Dee Dropped", "roles": ROLES["learner"], "status": "Inactive"},
    {"user_id": "learner-3", "name": "Eve Learner", "roles": ROLES["learner"]},
]


def new_key():
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    private = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    ).decode()
    public = key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    ).decode()
    return private, public


class Config(LTI1P3PlatformConfAbstract):
    def init_platform_config(self, **kwargs):
        self.settings = kwargs

    def get_registration_by_params(self, **kwargs):
        s = self.settings
        private, public = s["keys"]
        reg = Registration()
        reg.set_iss(s["issuer"]).set_client_id(CLIENT_ID).set_deployment_id(
            s.get("deployment_id", DEPLOYMENT_ID)
        )
        reg.set_oidc_login_url(s["tool"] + "/lti/login")
        reg.set_launch_url(s["tool"] + "/lti/launch")
        reg.set_deeplink_launch_url(s["tool"] + "/lti/launch")
        reg.set_tool_key_set_url(s["tool"] + "/lti/jwks")
        reg.set_platform_public_key(public).set_platform_private_key(private)
        return reg


class Req(Request):
    def build_metadata(self, request):
        return request


class Launch(LTIAdvantageMessageLaunchAbstract):
    tamper = None

    def render_launch_form(self, launch_data, **kwargs):
        return (
            '<!doctype html><form id="launch" method="post" action="%s">'
            '<input type="hidden" name="id_token" value="%s">'
            '<input type="hidden" name="state" value="%s"></form>'
            % (launch_data["launch_url"], launch_data["id_token"], launch_data["state"])
        )

    def generate_launch_request(self):
        data = super().generate_launch_request()
        if self.tamper == "signature":
            head, body, sig = data["id_token"].split(".")
            sig = ("A" if sig[0] != "A" else "B") + sig[1:]
            data["id_token"] = ".".join([head, body, sig])
        return data


def config():
    return Config(**SETTINGS)


class Ags(AssignmentsGradesService):
    def find_lineitems(self, page=1, limit=None, **filters):
        with LOCK:
            items = list(STORE["lineitems"].values())
        for k in ("resource_link_id", "resource_id", "tag"):
            if filters.get(k):
                key = {"resource_link_id": "resourceLinkId", "resource_id": "resourceId", "tag": "tag"}[k]
                items = [i for i in items if i.get(key) == filters[k]]
        return {"content": items, "has_next": False, "next": None}

    def find_lineitem(self, line_item_id):
        with LOCK:
            item = STORE["lineitems"].get(line_item_id)
        if item is None:
            raise LineItemNotFoundException()
        return item

    def create_lineitem(self, creation_data):
        return add_lineitem(creation_data)

    def update_lineitem(self, update_data):
        item = self.find_lineitem(update_data["id"].rsplit("/", 1)[-1])
        item.update({k: v for k, v in update_data.items() if k != "id"})
        return item

    def delete_lineitem(self, line_item_id):
        with LOCK:
            if STORE["lineitems"].pop(line_item_id, None) is None:
                raise LineItemNotFoundException()

    def update_score(self, line_item_id, score):
        self.find_lineitem(line_item_id)
        with LOCK:
            STORE["scores"].append({"lineitem": line_item_id, "score": score})
        return UpdateScoreStatus.SUCCESS

    def get_results(self, line_item_id, page=1, limit=None, user_id=None, **_):
        item = self.find_lineitem(line_item_id)
        latest = {}
        with LOCK:
            for s in STORE["scores"]:
                if s["lineitem"] == line_item_id:
                    latest[s["score"]["userId"]] = s["score"]
        results = [
            {
                "id": "%s/results/%s" % (item["id"], user),
                "userId": user,
                "resultScore": sc.get("scoreGiven"),
                "resultMaximum": sc.get("scoreMaximum", 1),
                "comment": sc.get("comment"),
                "scoreOf": item["id"],
            }
            for user, sc in latest.items()
            if user_id is None or user == user_id
        ]
        return {"content": results, "has_next": False, "next": None}


class Nrps(NamesRoleProvisioningService):
    def get_member_data_page(self, page=1, limit=None, role=None, since=None, **_):
        page, limit = int(page), int(limit or 2)
        members = MEMBERS[(page - 1) * limit : page * limit]
        return {"content": [dict(m) for m in members], "has_next": page * limit < len(MEMBERS)}

    def get_context_by_id(self):
        return Context(id=CONTEXT["id"], label=CONTEXT["label"], title=CONTEXT["title"])

    def is_resource_link_valid(self, context_id, resource_link_id):
        return resource_link_id in STORE["links"]


def add_lineitem(data):
    lid = uuid.uuid4().hex[:12]
    item = dict(data)
    item["id"] = "%s/ags/lineitems/%s" % (SETTINGS["issuer"], lid)
    with LOCK:
        STORE["lineitems"][lid] = item
    return item


class Handler(BaseHTTPRequestHandler):
    def log_message(self, fmt, *args):
        sys.stderr.write("platform: " + (fmt % args) + "\n")

    def reply(self, code, body, ctype="application/json", headers=()):
        data = body.encode() if isinstance(body, str) else json.dumps(body).encode()
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(data)))
        for k, v in headers:
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(data)

    def request_dict(self):
        url = urlparse(self.path)
        length = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(length) if length else b""
        ctype = self.headers.get("Content-Type", "")
        form, body = {}, None
        if ctype.startswith("application/x-www-form-urlencoded"):
            form = dict(parse_qsl(raw.decode()))
        elif raw:
            body = json.loads(raw)
        return url, {
            "method": self.command,
            "form_data": form,
            "get_data": dict(parse_qsl(url.query)),
            # HTTP header names are case-insensitive; the library looks them up as "Authorization".
            "headers": {k.title(): v for k, v in self.headers.items()},
            "content_type": ctype,
            "path": url.path,
            "json": body,
        }

    def service_reply(self, resp, link=None):
        headers = []
        result = resp.result
        if isinstance(result, dict) and result.get("next"):
            headers.append(("Link", '<%s>; rel="next"' % result["next"]))
        if result is None:
            result = {"message": resp.message}
        elif isinstance(result, dict) and "content" in result:
            result = result["content"]
        self.reply(resp.code, result, resp.media_type, headers)

    def do_GET(self):
        self.route()

    def do_POST(self):
        self.route()

    def do_PUT(self):
        self.route()

    def do_DELETE(self):
        self.route()

    def route(self):
        try:
            self.dispatch()
        except Exception as e:  # a test platform: report, never hang the test
            import traceback

            traceback.print_exc()
            self.reply(500, {"error": str(e)})

    def dispatch(self):
        url, req = self.request_dict()
        path, q = url.path, req["get_data"]
        issuer = SETTINGS["issuer"]
        if path == "/start":
            hint = uuid.uuid4().hex
            with LOCK:
                STORE["launches"][hint] = dict(q)
            params = {
                "iss": issuer,
                "login_hint": q.get("user", "learner-1"),
                "target_link_uri": SETTINGS["tool"] + "/lti/launch",
                "lti_message_hint": hint,
                "client_id": CLIENT_ID,
                "lti_deployment_id": q.get("deployment", DEPLOYMENT_ID),
            }
            return self.reply(302, "", "text/plain", [("Location", SETTINGS["tool"] + "/lti/login?" + urlencode(params))])
        if path == "/auth":
            with LOCK:
                settings = STORE["launches"].get(q.get("lti_message_hint"))
            if settings is None or q.get("redirect_uri") != SETTINGS["tool"] + "/lti/launch":
                return self.reply(400, {"error": "unknown message hint or redirect_uri"})
            if q.get("login_hint") != settings.get("user", "learner-1"):
                return self.reply(400, {"error": "login_hint is not the user who started"})
            return self.reply(200, launch_form(req, settings), "text/html")
        if path == "/jwks":
            return self.reply(200, config_with_registration().get_jwks())
        if path == "/token":
            cfg = config()
            cfg.get_registration()
            try:
                return self.reply(200, cfg.get_access_token(req["form_data"]))
            except Exception as e:
                return self.reply(400, {"error": "invalid_client", "error_description": str(e)})
        if path == "/deep-link-return":
            cfg = config()
            cfg.get_registration()
            items = cfg.validate_deeplinking_resp(req["form_data"])
            body = json.loads(_b64(req["form_data"]["JWT"].split(".")[1]))
            created = []
            for item in items:
                line = add_lineitem(dict(item["lineItem"], resourceLinkId="pending")) if item.get("lineItem") else None
                link_id = uuid.uuid4().hex[:10]
                if line:
                    line["resourceLinkId"] = link_id
                with LOCK:
                    STORE["links"][link_id] = {
                        "custom": item.get("custom", {}),
                        "lineitem": line["id"] if line else None,
                        "title": item.get("title", ""),
                    }
                created.append({"resource_link_id": link_id, "item": item, "lineitem": line})
            with LOCK:
                STORE["deep_link_items"].extend(created)
            return self.reply(200, {"links": created, "data": body.get("https://purl.imsglobal.org/spec/lti-dl/claim/data")})
        if path == "/debug/scores":
            with LOCK:
                return self.reply(200, list(STORE["scores"]))
        if path == "/nrps/memberships":
            # Two members per page, so that the tool follows Link rel=next; the library adds 1 to
            # the page number, so it must be an int.
            req["get_data"].setdefault("limit", "2")
            req["get_data"]["page"] = int(req["get_data"].get("page", 1))
            svc = Nrps(Req(req), config_with_registration(), issuer + "/nrps/memberships")
            return self.service_reply(svc.handle_resp(svc.handle_get_members))
        if path.startswith("/ags/lineitems"):
            rest = path[len("/ags/lineitems") :].strip("/").split("/")
            lineitem_url = issuer + "/ags/lineitems/" + rest[0] if rest[0] else None
            svc = Ags(Req(req), config_with_registration(), issuer + "/ags/lineitems", lineitem_url)
            if rest == [""]:
                fn = svc.handle_create_lineitem if self.command == "POST" else svc.handle_get_lineitems
                return self.service_reply(svc.handle_resp(fn))
            if len(rest) == 1:
                fn = {"GET": svc.handle_get_lineitem, "PUT": svc.handle_update_lineitem, "DELETE": svc.handle_delete_lineitem}[self.command]
                return self.service_reply(svc.handle_resp(fn, line_item_id=rest[0]))
            if rest[1] == "scores":
                return self.service_reply(svc.handle_resp(svc.handle_update_score, line_item_id=rest[0]))
            if rest[1] == "results":
                return self.service_reply(svc.handle_resp(svc.handle_get_results, line_item_id=rest[0]))
        return self.reply(404, {"error": "no such endpoint " + path})


def _b64(s):
    import base64

    return base64.urlsafe_b64decode(s + "=" * (-len(s) % 4))


def config_with_registration():
    cfg = config()
    cfg.get_registration()
    return cfg


def launch_form(req, settings):
    issuer = SETTINGS["issuer"]
    tamper = settings.get("tamper")
    launch = Launch(Req(req), config())
    launch.tamper = tamper
    user = settings.get("user", "learner-1")
    role = settings.get("role", "learner")
    launch.set_user_data(user, ROLES[role], full_name=settings.get("name", user), email_address=user + "@lms.example")
    launch.set_launch_context_claim(
        CONTEXT["id"],
        ["http://purl.imsglobal.org/vocab/lis/v2/course#CourseOffering"],
        CONTEXT["title"],
        CONTEXT["label"],
    )
    launch.set_nrps(issuer + "/nrps/memberships")
    if settings.get("message") == "deeplink":
        launch.set_dl(
            issuer + "/deep-link-return",
            title="Choose a station",
            accept_types={"ltiResourceLink"},
            extra_data="opaque-platform-data-7",
        )
    else:
        link = STORE["links"].get(settings.get("link", ""), {"custom": {}, "lineitem": None, "title": "Station"})
        launch.set_resource_link_claim(settings.get("link", "no-link"), title=link["title"])
        launch.set_custom_parameters_claim(link["custom"])
        launch.set_ags(issuer + "/ags/lineitems", link["lineitem"], True, True, True)
    if tamper == "expired":
        launch.set_id_token_expiration(-3600)
    if tamper == "audience":
        launch.set_extra_claims({"aud": "another-tool", "azp": "another-tool"})
    if tamper == "deployment":
        launch.set_extra_claims({"https://purl.imsglobal.org/spec/lti/claim/deployment_id": "unknown-deployment"})
    return launch.lti_launch()


def main():
    global SETTINGS
    tool = sys.argv[1].rstrip("/")
    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    port = server.server_address[1]
    SETTINGS = {"issuer": "http://127.0.0.1:%d" % port, "tool": tool, "keys": new_key()}
    print(json.dumps({"port": port, "issuer": SETTINGS["issuer"], "client_id": CLIENT_ID, "deployment_id": DEPLOYMENT_ID}), flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main()
