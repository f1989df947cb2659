"""The live service: recordings followed as they happen, alarm notifications, metrics.

``chaintwin serve --watch DIR --opcua CONFIG.yaml`` runs the sources in the
web service's process, or alone with ``--no-web``:

* :mod:`.sources` the contract of a live source (:data:`Submit`) and the
  ingest queue every source hands its recordings to;
* :mod:`.watch` watched folders (a full scan, then watchfiles; the settle time);
* :mod:`.opcua` drives followed over OPC UA (:mod:`.scope_layout` the scope
  buffer's default node layout, :mod:`.drive_sim` a simulated drive);
* :mod:`.ledger` what the service keeps in the store: refused files, the
  sources' state, leases;
* :mod:`.notify` the alarm notifications (outbox, signed webhooks);
* :mod:`.metrics` the Prometheus metrics; :mod:`.logs` JSON logs;
* :mod:`.retention` dropping old samples; :mod:`.service` all of it under asyncio.
"""
