"""Request-to-answer latency and answers per second of `pachs serve`: one client asking alone,
then C clients at once (threads, each its own connection and session), each request one
canonical instance; then many episodes at once (requests of 30). The server runs as `pachs
serve` in a subprocess (or at --url); each answer carries the server's search time, so the
overhead of the transport and the gathering window is latency - search time.

GPU (the issue's settings):
  python experiments/bench_serve.py --task pusht-obs --budget 10000 --clients 1,16 \\
      --requests 20 --max-batch 16 --big 30 --out experiments/results/serve_gpu
CPU (small):
  python experiments/bench_serve.py --budget 512 --clients 1,4 --requests 4 --max-batch 4 \\
      --big 4 --out experiments/results/serve_cpu
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from typing import Callable

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # pylint: disable=wrong-import-position

from pachs_jax import argtypes, client  # pylint: disable=wrong-import-position


def start_server(args, environ: dict) -> tuple:
  """(process, url, (s to ready, s to every bucket warm)) of `pachs serve` with the benchmark's
  settings, once every bucket is warm (it answers from the largest before)."""
  command = [sys.executable, '-m', 'pachs_jax.cli', 'serve', '--task', args.task, '--port', '0',
             '--max-batch', str(max([args.max_batch] + args.big_sizes)), '--window-ms', str(args.window_ms),
             '--backend', args.backend, '--devices', str(args.devices)]
  if args.budget:
    command += ['--budget', str(args.budget)]
  if args.buckets:
    command += ['--buckets', args.buckets]
  if args.split:
    command += ['--split', args.split]
  if args.max_wait_ms:
    command += ['--max-wait-ms', str(args.max_wait_ms)]
  if args.pop_size:
    command += ['-K', str(args.pop_size)]
  began = time.perf_counter()
  process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=environ)
  line = process.stdout.readline()
  found = re.search(r'ws://\S+', line)
  if not found:
    process.kill()
    raise SystemExit(f'bench_serve: the server did not start: {line!r}')
  ready_s = time.perf_counter() - began
  with client.Client(found.group(0), args.task) as asking:  # measured with every bucket warm
    while True:
      health = asking.health()
      if (health['tasks'][args.task]['warm_buckets'] == health['buckets']
          or process.poll() is not None):
        break
      time.sleep(0.2)
  return process, found.group(0), (ready_s, time.perf_counter() - began)


def at_once(count: int, ask: Callable[[int], None], what: str) -> float:
  """Runs ask(0), ..., ask(count - 1) in threads released together; the seconds from their
  release until the last returned. SystemExit naming the first failure (what: 'client', ...)."""
  go, failed = threading.Barrier(count + 1), []

  def run(i):
    go.wait()
    try:
      ask(i)
    except Exception as err:  # pylint: disable=broad-except
      failed.append(f'{what} {i}: {type(err).__name__}: {err}')
  threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(count)]
  for t in threads:
    t.start()
  go.wait()
  began = time.perf_counter()
  for t in threads:
    t.join()
  if failed:
    raise SystemExit(f'bench_serve: {len(failed)} of {count} {what}s failed; {failed[0]}')
  return time.perf_counter() - began


def run_clients(url: str, task: str, clients: int, requests: int, time_limit_s) -> dict:
  """Each of `clients` threads asks `requests` one-instance requests in turn; latencies (s),
  server search times, batch sizes and the aggregate answers per second."""
  connections = [client.Client(url, task) for _ in range(clients)]
  latency = [[] for _ in range(clients)]
  search = [[] for _ in range(clients)]
  batch = [[] for _ in range(clients)]

  def ask(c):
    for r in range(requests):
      began = time.perf_counter()
      answer = connections[c].plan(instances=[(c + r) % 30], seed=r, time_limit_s=time_limit_s,
                                   reset=True)
      latency[c].append(time.perf_counter() - began)
      search[c].append(answer.search_s)
      batch[c].append(answer.batch['requests'])
  try:
    wall = at_once(clients, ask, 'client')
  finally:
    for c in connections:
      c.close()
  lat, srch = np.concatenate(latency), np.concatenate(search)
  return {'clients': clients, 'requests_each': requests, 'answers': int(lat.size),
          'wall_s': wall, 'answers_per_s': lat.size / wall,
          'latency_median_s': float(np.median(lat)), 'latency_p90_s': float(np.quantile(lat, 0.9)),
          'search_median_s': float(np.median(srch)),
          'overhead_median_s': float(np.median(lat - srch)),
          'mean_requests_per_batch': float(np.mean(np.concatenate(batch)))}


CANONICAL = 30  # canonical instances of a PushT task


def run_big(url: str, task: str, instances: int, time_limit_s, repeats: int) -> dict:
  """`instances` episodes asked at once, `repeats` times: one request of them (at most the 30
  canonical instances), or requests of the 30 instances from as many clients, one seed each
  (30 instances x 5 seeds for 150: the open-loop protocol), which the server gathers into one
  search. Latency (until the last answer), search time and episodes whose answer reaches the
  goal."""
  parts = [min(CANONICAL, instances - i) for i in range(0, instances, CANONICAL)]
  connections, rows = [], []
  try:
    connections += [client.Client(url, task) for _ in parts]
    for r in range(repeats):
      answers = [None] * len(parts)

      def ask(p, r=r, answers=answers):
        answers[p] = connections[p].plan(instances=list(range(parts[p])),
                                         seed=r * len(parts) + p, time_limit_s=time_limit_s,
                                         reset=True)
      wall = at_once(len(parts), ask, 'request')
      rows.append((wall, max(a.search_s for a in answers),
                   sum(int(np.sum(np.asarray(a.reaches_goal))) for a in answers),
                   max(a.batch['requests'] for a in answers)))
  finally:
    for c in connections:
      c.close()
  lat, srch, found, together = np.array(rows).T
  return {'instances': instances, 'requests': len(parts), 'repeats': repeats,
          'latency_median_s': float(np.median(lat)), 'search_median_s': float(np.median(srch)),
          'overhead_median_s': float(np.median(lat - srch)),
          'reaching_goal_median': float(np.median(found)),
          'most_requests_in_one_search': int(np.max(together))}


def main() -> None:
  parser = argtypes.OneLineParser(description=__doc__.split('\n\n')[0])
  parser.add_argument('--task', default='pusht-obs')
  parser.add_argument('--backend', default='auto')
  parser.add_argument('--budget', type=argtypes.positive_int, default=None)
  parser.add_argument('--clients', default='1,16', help='client counts, comma-separated')
  parser.add_argument('--requests', type=argtypes.positive_int, default=20,
                      help='requests per client')
  parser.add_argument('--max-batch', type=argtypes.positive_int, default=16)
  parser.add_argument('--window-ms', type=argtypes.positive_float, default=5.0)
  parser.add_argument('--time-limit', type=argtypes.positive_float, default=None)
  parser.add_argument('--big', default='30',
                      help='episodes of the many-episode requests, comma-separated (0: none)')
  parser.add_argument('--big-repeats', type=argtypes.positive_int, default=3)
  parser.add_argument('--devices', type=argtypes.positive_int, default=1,
                      help="the started server's devices (pachs serve --devices)")
  parser.add_argument('--buckets', default=None,
                      help="the started server's buckets (pachs serve --buckets; default its own)")
  parser.add_argument('-K', '--pop-size', type=argtypes.positive_int, default=None,
                      help="the started server's edges per instance and iteration (pachs serve "
                      "-K; default the task's)")
  parser.add_argument('--max-wait-ms', type=argtypes.positive_float, default=None,
                      help="the started server's --max-wait-ms (default: none)")
  parser.add_argument('--split', choices=('mesh', 'threads'), default=None,
                      help="how the started server's devices share a batch (pachs serve --split)")
  parser.add_argument('--url', default=None, help='a running server (default: start one)')
  parser.add_argument('--out', required=True, help='directory for bench_serve.json and .md')
  args = parser.parse_args()
  # the server plans on the accelerators, with the environment as given; this process only asks
  # and stays off them, so that the two do not share a GPU's memory
  environ = dict(os.environ)
  os.environ.setdefault('JAX_PLATFORMS', 'cpu')
  common.check_out_folder(parser, args.out)
  if args.url is not None and not args.url.startswith(('ws://', 'wss://')):
    parser.error(f'--url {args.url!r}: a ws:// or wss:// address of a running pachs serve')
  try:
    big_sizes = [int(b) for b in args.big.split(',') if b]
    counts = [int(c) for c in args.clients.split(',') if c]
  except ValueError:
    parser.error(f'--big and --clients: comma-separated integers, got {args.big!r}, '
                 f'{args.clients!r}')
  if any(c < 1 for c in counts):
    parser.error(f'--clients: client counts must be >= 1, got {args.clients!r}')
  if any(b < 0 for b in big_sizes):
    parser.error(f'--big: episode counts must not be negative, got {args.big!r}')
  args.big_sizes = big_sizes = [b for b in big_sizes if b > 0]
  process, start_s, code = None, None, None
  url = args.url
  if url is None:
    process, url, start_s = start_server(args, environ)
  # a time limit's SIGTERM ends the benchmark like Ctrl-C: the server is stopped, and the
  # phases that finished were written as they finished
  signal.signal(signal.SIGTERM, signal.default_int_handler)
  runs, big, health = [], [], None
  try:
    with client.Client(url, args.task) as asking:
      health = asking.health()
    save(args, health, start_s, None, runs, big, finished=False)
    for c in counts:
      runs.append(run_clients(url, args.task, c, args.requests, args.time_limit))
      alone = next((r for r in runs if r['clients'] == 1), None)
      for r in runs:
        r['speedup_vs_alone'] = alone and r['answers_per_s'] / alone['answers_per_s']
      say(f'{c} client(s): {runs[-1]["answers"]} answers in {runs[-1]["wall_s"]:.1f} s')
      save(args, health, start_s, None, runs, big, finished=False)
    for b in big_sizes:
      big.append(run_big(url, args.task, b, args.time_limit, args.big_repeats))
      say(f'{args.big_repeats} requests of {b} episodes: latency {big[-1]["latency_median_s"]:.2f} s')
      save(args, health, start_s, None, runs, big, finished=False)
    with client.Client(url, args.task) as asking:
      health = asking.health()
  except KeyboardInterrupt:
    say('interrupted: the phases that finished are written')
  finally:
    if process is not None:
      if process.poll() is not None:
        say(f'the server had exited, with code {process.returncode}')
      process.send_signal(signal.SIGTERM)
      code = process.wait(60)
  if health is None:
    raise SystemExit('bench_serve: interrupted before the server answered; nothing written')
  finished = len(runs) == len(counts) and len(big) == len(big_sizes)
  print('\n'.join(save(args, health, start_s, code, runs, big, finished)))


def say(text: str) -> None:
  print(f'bench_serve: {text}', file=sys.stderr, flush=True)


def save(args, health: dict, start_s, code, runs: list, big: list, finished: bool) -> list:
  """Writes bench_serve.json and .md of the phases so far (finished: all of them ran); returns
  the markdown lines."""
  document = {'provenance': common.provenance(health.get('device')), 'settings': vars(args),
              'finished': finished,
              'server': {'start_to_ready_s': start_s and start_s[0],
                         'start_to_every_bucket_warm_s': start_s and start_s[1], 'exit_code': code,
                         'backend': health['backend'], 'buckets': health['buckets'],
                         'budget': health['tasks'][args.task]['budget'],
                         'physics': health['tasks'][args.task]['physics'],
                         'counters': health['counters']},
              'clients': runs, 'big_request': big}
  columns = ['clients', 'answers', 'answers_per_s', 'speedup_vs_alone', 'latency_median_s',
             'latency_p90_s', 'search_median_s', 'overhead_median_s', 'mean_requests_per_batch']
  lines = [f'# pachs serve: latency and answers per second ({args.task})', '',
           f'Device: {document["provenance"]["device"]}; server devices {args.devices}; physics '
           f'{document["server"]["physics"]}; budget {document["server"]["budget"]} evaluations '
           f'per request; buckets {health["buckets"]}; window {args.window_ms:g} ms'
           + (f', restarting up to {args.max_wait_ms:g} ms' if args.max_wait_ms else '')
           + (f'; devices split: {args.split or "mesh"}' if args.devices > 1 else '')
           + (f'; K {args.pop_size}' if args.pop_size else '') + '.'
           + (f' Start to ready {start_s[0]:.1f} s, to every bucket warm {start_s[1]:.1f} s.'
              if start_s else ''),
           f'Command: `{document["provenance"]["command"]}` at '
           f'{document["provenance"]["git_revision"]}.', '',
           common.markdown_table(runs, columns) if runs else '']
  for b in big:
    lines += ['', f'{b["instances"]} episodes in {b.get("requests", 1)} request(s) at once '
              f'(median of {b["repeats"]}; at most {b.get("most_requests_in_one_search", 1)} '
              f'in one search): '
              f'latency {b["latency_median_s"]:.3f} s, search {b["search_median_s"]:.3f} s, '
              f'overhead {b["overhead_median_s"]:.3f} s, reaching the goal '
              f'{b["reaching_goal_median"]:g}.']
  if not finished:
    lines += ['', 'Not finished: the phases above are those that ran.']
  common.write_result(os.path.join(args.out, 'bench_serve.json'), document, lines)
  return lines

if __name__ == '__main__':
  main()
