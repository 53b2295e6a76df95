"""Alerting: rules that turn what the station hears into notifications that get delivered.

``rules`` (the rules file and pure matching), ``channels`` (webhook, e-mail), ``db`` (the
alert tables in the station database), ``outbox`` (persistent deliveries with retries),
``engine`` (events -> alerts: dedup, rate limit, digest, escalation, acknowledgement),
``service`` (the thread that runs the engine and delivers). docs/station.md "Alerts".
"""
