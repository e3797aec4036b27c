"""The worker processes that fly an experiment's runs, a tuning's candidates and a report's figures."""
import concurrent.futures as cf
import os
import signal
import sys


def _worker_init():
    # one thread per worker process: the processes are the parallelism
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    # Ctrl-C reaches the whole process group: the parent answers it and stops the workers,
    # which would otherwise each print a traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)



def default_workers(workers=None):
    """Worker processes to use: ``workers``, or one per core."""
    return workers if workers is not None else (os.cpu_count() or 1)



def process_pool(workers):
    """The worker pool of experiment runs, tuning candidates and report figures: fresh
    interpreters (forkserver; spawn off Linux) that load the compiled kernels from numba's
    cache, one numba thread each."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn" if sys.platform != "linux" else "forkserver")
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init)



def stop_pool(pool):
    """Stop a process pool now: the queued runs cancelled, the workers terminated, and the
    pool's manager thread waited for as it fails what was pending and closes its pipes (left
    running, it raced the interpreter's exit, which writes to one of them: a traceback after
    the one line, now and then, on a loaded machine)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.join(5)
    if manager is not None:
        manager.join(5)
