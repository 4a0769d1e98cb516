"""kombu's SQLAlchemy transport, tuned for the server-less embedded farm on SQLite.

Registered as the ``tweensqla`` transport alias (URL ``tweensqla+sqlite:///path``). Two
changes from ``sqla`` that the stock transport cannot take as options (it passes every
transport option to ``create_engine``): a 0.1 s polling interval instead of 1 s, so a
four-stage job does not wait seconds between stages; and SQLite connections that are never
shared across ``fork`` (prefork children publish the next stage of a chain themselves).
And a deleted queue really goes, with its delivered messages (the embedded farm deletes each
run's private queue when the run ends). And a message that cannot be written because the
disk is full is one error naming the broker's folder (kombu took SQLite's SQLITE_FULL for a
lost connection, retried on a channel it had closed, and died of an AttributeError).
"""

from __future__ import annotations

import os
from contextlib import contextmanager

from kombu.transport import TRANSPORT_ALIASES
from kombu.transport import sqlalchemy as kombu_sqla

from workers.errors import StoreFullError, end_for_full_store, store_full

ALIAS = "tweensqla"


def broker_folder(url: str) -> str:
    """The folder of the SQLite file of a broker URL (``[tweensqla+]sqlite:///PATH``)."""
    return os.path.dirname(str(url).split(":///", 1)[-1].split("?", 1)[0]) or "."


class Channel(kombu_sqla.Channel):
    @contextmanager
    def _room(self):
        """A full disk while publishing, or taking a message (which marks it taken), is
        StoreFullError, which kombu does not retry (it took SQLITE_FULL for a lost connection
        and retried on the channel it had closed); an embedded worker then ends."""
        folder = broker_folder(self.connection.client.hostname)
        try:
            yield
        except Exception as e:
            if not store_full(e, folder):
                raise
            try:
                self.session.rollback()  # the failed write, so that the session can be closed
            except Exception:  # the full disk may refuse that too: the error stands
                pass
            end_for_full_store()
            raise StoreFullError(folder) from None

    def _new_queue(self, queue, **kwargs):
        with self._room():
            return super()._new_queue(queue, **kwargs)

    def _put(self, queue, payload, **kwargs):
        with self._room():
            return super()._put(queue, payload, **kwargs)

    def _get(self, queue):
        with self._room():
            return super()._get(queue)

    def queue_delete(self, queue, if_unused=False, if_empty=False, **kwargs):
        """Deletes the queue whether or not this process declared it (the stock virtual
        channel deletes only the bindings it knows of)."""
        if if_empty and self._size(queue):
            return
        self._delete(queue)
        self.state.queue_bindings_delete(queue)

    def _delete(self, queue, *args, **kwargs):
        """A deleted queue leaves the database with all its messages (the stock transport
        keeps delivered messages, and the queue row, for good)."""
        self._purge(queue)
        self.session.query(self.queue_cls).filter(self.queue_cls.name == queue).delete(
            synchronize_session=False
        )
        self.session.commit()

    def _engine_from_config(self):
        from sqlalchemy import create_engine

        # 30 s busy timeout: the worker's main process and its children write to one file.
        return create_engine(self.connection.client.hostname, connect_args={"timeout": 30})


class Transport(kombu_sqla.Transport):
    Channel = Channel
    polling_interval = 0.1


def _dispose_after_fork() -> None:
    for engine, _ in list(kombu_sqla.Channel._engines.values()):
        engine.dispose(close=False)  # forget the parent's pooled connections, do not close them


os.register_at_fork(after_in_child=_dispose_after_fork)
TRANSPORT_ALIASES.setdefault(ALIAS, "workers.sqlite_transport:Transport")
