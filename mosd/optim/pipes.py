"""A direct pipe to each worker of the process pool, for the generations of one tuning.

A pool task per chunk costs a generation more than the chunk's work on a many-core machine:
loky hands each task through a queue-feeding thread and each result through its manager
thread, and both wait for the GIL that the main thread holds while it evaluates its own chunk.
On 16 cores that was 17-31 ms per generation for 15 chunks of 1-3 ms of work each
(``python -m mosd.bench --only scale``, docs/SCALING.md). Here each pool worker instead runs one
long task, :func:`serve`, connected to the main process by a Unix socket of its own; a
generation writes each worker its chunk and reads its answer on that socket, from the main
thread, with no other thread in between.

The workers are still the pool's (:func:`mosd.optim.problem.worker_pool`): started ahead,
reused between problems, ended by the run's signal handling like any pool worker. While a
:class:`WorkerPipes` is open its tasks hold every worker; :meth:`WorkerPipes.close` (from
:meth:`mosd.optim.problem.TuningProblem.close`, and when the object is collected) ends them,
and the workers go back to the pool.
"""
from __future__ import annotations

import concurrent.futures
import os
import shutil
import socket
import struct
import tempfile
import time
import weakref
from multiprocessing.connection import Connection, wait

#: seconds to wait for every worker to connect (a pool started ahead is up long before)
CONNECT_TIMEOUT_S = 600.0


class WorkerFailure(RuntimeError):
    """An evaluation worker ended or could not answer (killed, out of memory): the pipes are closed."""


def serve(address: str, setup, argument) -> int:
    """A pool task: connect to ``address``, build ``handler = setup(argument)``, answer each message with it.

    Runs until the main process sends None or closes its end. An exception raised by the handler is sent
    back in place of the answer (the main process raises it), and the task goes on serving. Returns the
    number of messages answered.
    """
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(address)
    connection = Connection(sock.detach())
    answered = 0
    with connection:
        handler = setup(argument)
        while True:
            try:
                message = connection.recv()
            except (EOFError, OSError):  # the main process went away or closed: the task ends
                return answered
            if message is None:
                return answered
            try:
                answer = handler(message)
            except BaseException as error:  # noqa: BLE001 - the main process decides what it means
                answer = _Raised(error)
            try:
                connection.send(answer)
            except (BrokenPipeError, OSError):
                return answered
            answered += 1


class _Raised:
    """An exception raised in a worker, carried back (the exception itself when it pickles, else its text)."""

    def __init__(self, error: BaseException):
        import pickle

        try:
            pickle.dumps(error)
            self.error = error
        except Exception:  # an exception holding something unpicklable: its type and text still say what failed
            self.error = RuntimeError(f"{type(error).__name__}: {error}")


class WorkerPipes:
    """One socket to each of ``n_workers`` workers of ``executor``, each serving ``setup(argument)``.

    Parameters
    ----------
    executor : concurrent.futures.Executor
        The process pool; ``n_workers`` of its workers are held until :meth:`close`.
    n_workers : int
        Workers to connect (the pool's size: a task per worker).
    setup : callable
        A module-level function (pickled by reference) that a worker calls once with ``argument`` to build
        its handler: message -> answer.
    """

    def __init__(self, executor, n_workers: int, setup, argument, timeout: float = CONNECT_TIMEOUT_S):
        self._directory = tempfile.mkdtemp(prefix="mosd-pipes-")  # 0700: only this user can connect
        address = os.path.join(self._directory, "socket")
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.connections: list[Connection] = []
        self.pids: list[int | None] = []  # the process at the other end of each connection (None: not known)
        self._futures: list = []
        self._finalizer = weakref.finalize(self, _close, self.connections, self._futures, self._directory)
        try:
            listener.bind(address)
            listener.listen(n_workers)
            listener.settimeout(0.2)
            self._futures.extend(executor.submit(serve, address, setup, argument) for _ in range(n_workers))
            deadline = time.monotonic() + timeout
            while len(self.connections) < n_workers:
                try:
                    sock, _ = listener.accept()
                except TimeoutError:
                    failed = next((f for f in self._futures if f.done()), None)
                    if failed is not None:  # a task that ended before connecting: its error says why
                        failed.result()
                        raise WorkerFailure("an evaluation worker ended before it connected")
                    if time.monotonic() > deadline:
                        raise WorkerFailure(f"the evaluation workers did not connect within {timeout:g} s") from None
                    continue
                sock.setblocking(True)
                self.pids.append(_peer_pid(sock))
                self.connections.append(Connection(sock.detach()))
        except BaseException:
            self.close()
            raise
        finally:
            listener.close()

    def __len__(self) -> int:
        return len(self.connections)

    def send(self, index: int, message) -> None:
        """Write ``message`` to worker ``index``."""
        try:
            self.connections[index].send(message)
        except (BrokenPipeError, ConnectionError, OSError) as error:
            raise self._failed(error) from None

    def receive(self, indices) -> dict:
        """The answers of the workers ``indices`` (each sent one message), as they arrive: {index: answer}.

        An exception a worker raised is raised here (after every answer is read, so that the pipes stay in
        step); a worker that ended raises :class:`WorkerFailure`.
        """
        pending = {self.connections[i]: i for i in indices}
        answers: dict = {}
        while pending:
            for connection in wait(list(pending)):
                index = pending.pop(connection)
                try:
                    answers[index] = connection.recv()
                except (EOFError, ConnectionError, OSError) as error:
                    raise self._failed(error) from None
        for answer in answers.values():
            if isinstance(answer, _Raised):
                raise answer.error
        return answers

    def _failed(self, error: BaseException) -> WorkerFailure:
        self.close()
        return WorkerFailure(f"an evaluation worker ended during the evaluation ({type(error).__name__}: {error}); "
                             "the run stops (out of memory, or a signal, can end a worker)")

    @property
    def closed(self) -> bool:
        return not self._finalizer.alive

    def close(self) -> None:
        """End the workers' tasks (they go back to the pool) and remove the socket's directory. Idempotent."""
        self._finalizer()


def _peer_pid(sock: socket.socket) -> int | None:
    """The process id at the other end of a connected Unix socket (Linux's ``SO_PEERCRED``), or None elsewhere."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return None
    pid, _uid, _gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    return pid


def _close(connections: list, futures: list, directory: str) -> None:
    for connection in connections:
        try:
            connection.send(None)
        except (BrokenPipeError, ConnectionError, OSError):
            pass
        connection.close()
    connections.clear()
    # the tasks end on the None (or the closed socket): wait a little so that the workers are free for the
    # next user of the pool; a task that never started (its worker died) is cancelled
    for future in futures:
        future.cancel()
    concurrent.futures.wait(futures, timeout=5.0)
    futures.clear()
    shutil.rmtree(directory, ignore_errors=True)
