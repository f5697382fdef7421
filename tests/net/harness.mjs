// harness.mjs - start the real `squish serve` binary ($SQUISH) on a free loopback port for a test.
import { spawn } from 'node:child_process';
import { readFileSync } from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

export const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const SQUISH = process.env.SQUISH || path.join(ROOT, 'build/squish');

/**
 * Start a server with extra flags; resolves with { url (ws), http, port, proc, pid, stop }.
 * Port 0 lets the kernel pick a free port; the server prints the one it got.
 */
export function startServer(args = [], { env = {}, prefix = [] } = {}) {
  // for sanitizer builds: OSMesa's own allocations are not ours
  const lsan = `suppressions=${path.join(ROOT, 'tests/net/lsan.supp')}`;
  // without --scenes the server would offer the shipped scenes it finds: these tests use the
  // built-in cube ("default") unless they name a directory
  const scenes = args.includes('--scenes') ? [] : ['--no-scenes'];
  // prefix: a command that execs the server (e.g. prlimit), so that proc.pid stays the server's
  const argv = [SQUISH, 'serve', '--host', '127.0.0.1', '--port', '0', ...scenes, ...args];
  const proc = spawn(prefix.length ? prefix[0] : SQUISH, prefix.length ? [...prefix.slice(1), ...argv] : argv.slice(1), {
    env: { LSAN_OPTIONS: lsan, ...process.env, ...env }, stdio: ['ignore', 'pipe', 'pipe'],
  });
  let out = '', err = '';
  proc.stderr.on('data', d => { err += d; });
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => { proc.kill('SIGKILL'); reject(new Error(`server did not start: ${err}`)); }, 15000);
    proc.on('exit', code => { clearTimeout(timer); reject(new Error(`server exited with ${code}: ${err}`)); });
    proc.stdout.on('data', d => {
      out += d;
      const m = out.match(/listening on http:\/\/127\.0\.0\.1:(\d+)\//);
      if (!m) return;
      clearTimeout(timer);
      proc.removeAllListeners('exit');
      const port = Number(m[1]);
      const exited = new Promise(res => proc.on('exit', (code, signal) => res({ code, signal })));
      resolve({
        port, proc, pid: proc.pid,
        url: `ws://127.0.0.1:${port}/ws`,
        http: `http://127.0.0.1:${port}`,
        stderr: () => err,
        exited,
        /** stop with a signal; resolves with { code, signal } */
        async stop(signal = 'SIGTERM', graceMs = 5000) {
          if (proc.exitCode === null && proc.signalCode === null) proc.kill(signal);
          // never leave a server behind: kill it if it does not stop in time
          const timer = setTimeout(() => proc.kill('SIGKILL'), graceMs);
          const r = await exited;
          clearTimeout(timer);
          // a server built with sanitizers reports memory errors on stderr: fail the test
          const bad = err.match(/(ERROR: (Address|Leak)Sanitizer|runtime error:).*/);
          if (bad) throw new Error(`server sanitizer report: ${bad[0]}\n${err.slice(0, 4000)}`);
          return r;
        },
      });
    });
  });
}

/** resident memory of a process in KiB (/proc/PID/status VmRSS) */
export function rssKiB(pid) {
  const m = readFileSync(`/proc/${pid}/status`, 'utf8').match(/VmRSS:\s+(\d+)\s+kB/);
  return m ? Number(m[1]) : NaN;
}

export const sleep = ms => new Promise(r => setTimeout(r, ms));

/**
 * Write a scene directory with a box body of n cells per side (mesh made by `squish mesh box`),
 * bottom fixed, gravity on; returns the directory. Used where the default cube is too small.
 */
export async function makeBoxScene(dir, name, n, { frameRate = 50 } = {}) {
  const { mkdirSync, writeFileSync } = await import('node:fs');
  const { execFileSync } = await import('node:child_process');
  mkdirSync(dir, { recursive: true });
  execFileSync(SQUISH, ['mesh', 'box', String(n), String(n), String(n), '--out', path.join(dir, `${name}.msh`)]);
  writeFileSync(path.join(dir, `${name}.json`), JSON.stringify({
    name, description: `${n}^3-cell box (net tests)`, gravity: [0, 0, -9.81], frame_rate: frameRate,
    bodies: [{
      name: 'box', levels: [`${name}.msh`],
      material: { lambda: 100000, mu: 40000, density: 1000, damping: { rayleigh_mass: 2.0, rayleigh_stiffness: 0.0 } },
      fixed: [{ box: [[-1, -1, -1], [2, 2, 0.001]] }],
    }],
  }));
  return dir;
}
