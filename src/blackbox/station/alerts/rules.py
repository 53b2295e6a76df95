"""Alert rules: what to match and where to send it, read from YAML, matched without I/O.

An on-call engineer writes one file (``blackbox station --alerts FILE``) naming the channels
(webhook, e-mail) and the rules; admins may add rules in the page, in the same YAML form,
checked by the same code. Every mistake is one :class:`~blackbox.config.node.ConfigError`
naming file, line and key path, so the station refuses to start (exit 2) rather than
silently never alerting.

Matching is pure (:func:`Rule.matches`): the engine hands it an :class:`AlertInput` and
gets a yes or no, which is what the tests pin down.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import yaml

from blackbox.config.node import ConfigError, ConfigNode

ALERT_KINDS = ("failure", "exceedance", "diagnosis", "robot_silent", "station_problem")
"""What a rule can match: a diagnosed failure, a threshold exceedance, a change of the
robot's diagnosis, a robot that went silent, a problem of the station itself."""

STATUSES = ("OPERATIONAL", "DEGRADED", "NOT_OPERATIONAL", "UNKNOWN")
CHANNEL_TYPES = ("webhook", "email")
MAX_RULES = 500


@dataclass(frozen=True, slots=True)
class WebhookSettings:
    """POST the JSON body to ``url``, signed with HMAC-SHA256 of ``secret``."""

    url: str
    secret: str
    timeout: float = 5.0


@dataclass(frozen=True, slots=True)
class EmailSettings:
    """Send through an SMTP server; ``starttls`` upgrades the connection before log-in."""

    host: str
    port: int
    sender: str
    to: tuple[str, ...]
    starttls: bool = True
    username: str = ""
    password: str = ""
    timeout: float = 10.0


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    name: str
    type: str
    webhook: WebhookSettings | None = None
    email: EmailSettings | None = None


@dataclass(frozen=True, slots=True)
class Delivery:
    """How hard the outbox tries: ``attempts`` in all, the first retry after ``backoff``
    seconds, each later one waiting twice as long, never more than ``max_backoff``."""

    attempts: int = 8
    backoff: float = 2.0
    max_backoff: float = 300.0

    def delay(self, attempt: int) -> float:
        """Seconds to wait after failed attempt number ``attempt`` (1 = the first)."""
        return float(min(self.max_backoff, self.backoff * 2.0 ** max(0, attempt - 1)))


@dataclass(frozen=True, slots=True)
class Escalation:
    after: float
    """Seconds after the alert fired without acknowledgement."""
    send: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class RateLimit:
    count: int
    per: float


@dataclass(frozen=True, slots=True)
class AlertInput:
    """One thing the station noticed, as a rule sees it. ``robot`` is ``station`` for a
    station problem; ``status`` is the robot's status when it happened."""

    kind: str
    robot: str
    entity: str
    status: str
    text: str
    time: float
    event_id: int | None = None


@dataclass(frozen=True, slots=True)
class Rule:
    name: str
    send: tuple[str, ...]
    robots: tuple[str, ...] = ()
    """Robot names or globs; empty: any robot (combined with ``site``)."""
    site_robots: tuple[str, ...] = ()
    """The robots (names or globs) of the sites named in ``match.site``."""
    entities: tuple[str, ...] = ()
    kinds: tuple[str, ...] = ALERT_KINDS
    statuses: tuple[str, ...] = ()
    lasting: float = 0.0
    """Seconds the condition must last (not be rectified) before the alert fires."""
    escalate: tuple[Escalation, ...] = ()
    rate_limit: RateLimit = RateLimit(10, 600.0)
    source: str = "file"
    text: str = ""
    """The rule as YAML (shown in the page, stored for page rules)."""

    def matches(self, event: AlertInput) -> bool:
        if event.kind not in self.kinds:
            return False
        if self.robots and not _any_glob(event.robot, self.robots):
            return False
        if self.site_robots and not _any_glob(event.robot, self.site_robots):
            return False
        if self.entities and not _any_glob(event.entity, self.entities):
            return False
        return not self.statuses or event.status in self.statuses

    @property
    def channels(self) -> tuple[str, ...]:
        """Every channel the rule may use, first the first step's."""
        seen: list[str] = list(self.send)
        for step in self.escalate:
            seen.extend(c for c in step.send if c not in seen)
        return tuple(seen)


def _any_glob(value: str, patterns: Sequence[str]) -> bool:
    return any(fnmatch.fnmatchcase(value, p) for p in patterns)


@dataclass(frozen=True, slots=True)
class AlertConfig:
    file: str
    channels: Mapping[str, ChannelSpec] = field(default_factory=lambda: MappingProxyType({}))
    rules: tuple[Rule, ...] = ()
    delivery: Delivery = Delivery()
    sites: Mapping[str, tuple[str, ...]] = field(default_factory=lambda: MappingProxyType({}))
    station_url: str = ""
    """How notifications link back to the station (``ack`` links); empty: no link."""


def load_alert_config(path: str | Path) -> AlertConfig:
    """Read and check a rules file; raises ConfigError naming file, line and key path."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError("is a directory, not an alert rules file", str(p))
    root = ConfigNode.load(p)
    return alert_config_from(root)


def alert_config_from(root: ConfigNode) -> AlertConfig:
    if root.is_null or not root.is_map:
        raise root.error("an alert rules file is a mapping with 'channels' and 'rules'")
    root.check_keys(["channels", "rules", "delivery", "sites", "station_url"])
    channels = {name: _channel(name, node)
                for name, node in (root["channels"].items() if root.get("channels") else ())}
    sites = {name: node.str_list()
             for name, node in (root["sites"].items() if root.get("sites") else ())}
    delivery = _delivery(root.get("delivery"))
    rules_node = root.get("rules")
    items = rules_node.list() if rules_node is not None else []
    if len(items) > MAX_RULES:
        raise rules_node.error(f"at most {MAX_RULES} rules")  # type: ignore[union-attr]
    rules: list[Rule] = []
    for item in items:
        rule = parse_rule(item, channels, sites, "file")
        if any(r.name == rule.name for r in rules):
            raise item["name"].error(f"a rule named {rule.name!r} exists already")
        rules.append(rule)
    url = root.get("station_url")
    return AlertConfig(root.file, MappingProxyType(channels), tuple(rules), delivery,
                       MappingProxyType(sites), url.str().rstrip("/") if url else "")


def parse_rule_text(text: str, config: AlertConfig, source: str = "page",
                    name: str = "<rule>") -> Rule:
    """One rule written in the page (YAML), checked against the configured channels."""
    if len(text) > 20_000:
        raise ConfigError("a rule is at most 20,000 characters", name)
    root = ConfigNode.parse(text, name)
    return dataclasses.replace(parse_rule(root, config.channels, config.sites, source),
                               text=text)


def parse_rule(node: ConfigNode, channels: Mapping[str, ChannelSpec],
               sites: Mapping[str, tuple[str, ...]], source: str) -> Rule:
    if not node.is_map:
        raise node.error("a rule is a mapping with 'name', 'match' and 'send'")
    node.check_keys(["name", "match", "send", "escalate", "rate_limit"])
    name = node["name"].str()
    if len(name) > 100:
        raise node["name"].error("a rule name has at most 100 characters")
    send = _channel_names(node["send"], channels)
    match = node.get("match")
    robots: tuple[str, ...] = ()
    site_robots: tuple[str, ...] = ()
    entities: tuple[str, ...] = ()
    kinds: tuple[str, ...] = ALERT_KINDS
    statuses: tuple[str, ...] = ()
    lasting = 0.0
    if match is not None:
        match.check_keys(["robot", "site", "entity", "kind", "status", "lasting"])
        robots = _strings(match.get("robot"))
        site_node = match.get("site")
        if site_node is not None:
            collected: list[str] = []
            for site_name in site_node.str_list():
                if site_name not in sites:
                    raise site_node.error(f"unknown site {site_name!r}; sites: "
                                          f"{', '.join(sites) or 'none defined'}")
                collected.extend(sites[site_name])
            site_robots = tuple(collected)
        entities = _strings(match.get("entity"))
        if match.get("kind") is not None:
            kinds = tuple(_choice(match["kind"], ALERT_KINDS))
        if match.get("status") is not None:
            statuses = tuple(_choice(match["status"], STATUSES))
        if match.get("lasting") is not None:
            lasting = match["lasting"].float(min=0.0, max=7 * 86400.0)
    escalate: list[Escalation] = []
    esc_node = node.get("escalate")
    previous = 0.0
    for step in esc_node.list() if esc_node is not None else []:
        step.check_keys(["after", "send"])
        after = step["after"].float(min=0.0, max=7 * 86400.0)
        if after < previous:
            raise step["after"].error(f"escalation steps come in order of time; {after:g} s "
                                      f"is before the previous step's {previous:g} s")
        previous = after
        escalate.append(Escalation(after, _channel_names(step["send"], channels)))
    limit = RateLimit(10, 600.0)
    limit_node = node.get("rate_limit")
    if limit_node is not None:
        limit_node.check_keys(["count", "per"])
        limit = RateLimit(limit_node["count"].int(min=1, max=10_000),
                          limit_node["per"].float(min=1.0, max=7 * 86400.0))
    return Rule(name, send, robots, site_robots, entities, kinds, statuses, lasting,
                tuple(escalate), limit, source,
                yaml.safe_dump(node.to_python(), sort_keys=False).strip())


def _strings(node: ConfigNode | None) -> tuple[str, ...]:
    return () if node is None else node.str_list()


def _choice(node: ConfigNode, choices: Sequence[str]) -> list[str]:
    items = node.list(allow_single=True)
    return [item.str(choices) for item in items]


def _channel_names(node: ConfigNode, channels: Mapping[str, ChannelSpec]) -> tuple[str, ...]:
    names = node.str_list()
    if not names:
        raise node.error("name at least one channel")
    for item, name in zip(node.list(allow_single=True), names, strict=True):
        if name not in channels:
            raise item.error(f"unknown channel {name!r}; channels: "
                             f"{', '.join(channels) or 'none defined'}")
    return names


def _secret(node: ConfigNode, key: str) -> str:
    """``key`` given literally, or ``key_env`` naming an environment variable (so the file
    can be shared without the secret)."""
    literal, env = node.get(key), node.get(f"{key}_env")
    if literal is not None and env is not None:
        raise env.error(f"give {key!r} or {key + '_env'!r}, not both")
    if env is not None:
        value = os.environ.get(env.str())
        if not value:
            raise env.error(f"environment variable {env.str()!r} is not set")
        return value
    return literal.str() if literal is not None else ""


def _channel(name: str, node: ConfigNode) -> ChannelSpec:
    if not node.is_map:
        raise node.error("a channel is a mapping with 'type' (webhook or email)")
    kind = node["type"].str(CHANNEL_TYPES)
    if kind == "webhook":
        node.check_keys(["type", "url", "secret", "secret_env", "timeout"])
        url = node["url"].str()
        if not url.startswith(("http://", "https://")):
            raise node["url"].error("a webhook URL starts with http:// or https://")
        secret = _secret(node, "secret")
        if len(secret) < 16:
            raise (node.get("secret") or node.get("secret_env") or node).error(
                "a webhook needs a 'secret' (or 'secret_env') of at least 16 characters to "
                "sign its requests")
        timeout = node["timeout"].float(min=0.1, max=60.0) if node.get("timeout") else 5.0
        return ChannelSpec(name, kind, webhook=WebhookSettings(url, secret, timeout))
    node.check_keys(["type", "host", "port", "from", "to", "starttls", "username", "password",
                     "password_env", "timeout"])
    to = node["to"].str_list()
    if not to or any("@" not in a for a in to):
        raise node["to"].error("'to' is one or more e-mail addresses")
    sender = node["from"].str()
    if "@" not in sender:
        raise node["from"].error("'from' is an e-mail address")
    username = node["username"].str() if node.get("username") else ""
    password = _secret(node, "password")
    if bool(username) != bool(password):
        raise node.error("'username' and 'password' (or 'password_env') go together")
    return ChannelSpec(name, kind, email=EmailSettings(
        node["host"].str(), node["port"].int(min=1, max=65535) if node.get("port") else 587,
        sender, to, node["starttls"].bool() if node.get("starttls") is not None else True,
        username, password,
        node["timeout"].float(min=0.1, max=120.0) if node.get("timeout") else 10.0))


def _delivery(node: ConfigNode | None) -> Delivery:
    if node is None:
        return Delivery()
    node.check_keys(["attempts", "backoff", "max_backoff"])
    d = Delivery()
    return Delivery(
        node["attempts"].int(min=1, max=100) if node.get("attempts") else d.attempts,
        node["backoff"].float(min=0.01, max=3600.0) if node.get("backoff") else d.backoff,
        node["max_backoff"].float(min=0.01, max=86400.0) if node.get("max_backoff")
        else d.max_backoff)
