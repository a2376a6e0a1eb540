#!/usr/bin/env python3
"""Checks tests/sanitizer_skips.txt: the tests the ASan/UBSan stage leaves out
must run no line and no branch of brdfkit's sources that the tests it keeps do
not run.

It builds the suite with clang's source-based coverage in its own tree (no
sanitizers, -O1), runs every test executable without the skipped tests (the
kept set, as the sanitizer stage runs it) and then each skipped test alone,
and compares the lines and branches of brdf/, validate/, data_synth/, fit/,
formats/ and cli/ that each one reaches (llvm-cov's lcov export; the tests'
own sources are not counted). Exit 0 when every test of the list's [covered]
section is covered by the kept ones, 1 (with the lines it alone runs)
otherwise, 2 on a usage or build error; for the [cost] section the code each
alone runs is printed.

  /usr/bin/python3 tests/sanitizer_skips_check.py [--tree build-coverage] [--jobs 2] [--list FILE]
      [--only NAME,NAME...]

On 2 cores the build takes about 9 minutes and the kept runs about 8
(2026-12-07); each listed test alone takes seconds to minutes, the [cost]
section's fits up to half an hour each, so --only runs just the names given
(the rest of the list stays out of the kept tests as well).
"""
import argparse
import concurrent.futures
import fnmatch
import glob
import os
import queue
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SKIPS = os.path.join(ROOT, 'tests', 'sanitizer_skips.txt')
EXECUTABLES = ['brdf_tests', 'validate_tests', 'data_synth_tests', 'fit_tests', 'formats_tests', 'cli_tests',
               'tests_tests']
LIBRARY_DIRS = ('brdf/', 'validate/', 'data_synth/', 'fit/', 'formats/', 'cli/')


def fail(message):
    print(message, file=sys.stderr)
    sys.exit(2)


def read_skips(path):
    """(test name, section) pairs, one name per line; '#' starts a comment,
    [covered] and [cost] start sections (names before any are [covered])."""
    names, section = [], 'covered'
    try:
        with open(path, encoding='utf-8') as f:
            for number, line in enumerate(f, 1):
                name = line.split('#', 1)[0].strip()
                if name.startswith('['):
                    if name not in ('[covered]', '[cost]'):
                        fail(f'{path}:{number}: unknown section {name} (sections: [covered], [cost])')
                    section = name[1:-1]
                elif name:
                    if ' ' in name:
                        fail(f'{path}:{number}: one test name per line, got "{name}"')
                    names.append((name, section))
    except OSError as e:
        fail(f'{path}: {e.strerror}')
    return names


def tool(*names):
    for n in names:
        if shutil.which(n):
            return n
    fail(f'none of {", ".join(names)} found (Debian: apt-get install clang llvm)')


def build(tree, jobs):
    flags = '-fprofile-instr-generate -fcoverage-mapping'
    subprocess.run(['cmake', '-S', ROOT, '-B', tree, '-DCMAKE_BUILD_TYPE=Release',
                    f'-DCMAKE_CXX_COMPILER={tool("clang++", "clang++-14")}', '-DCMAKE_CXX_FLAGS_RELEASE=-O1 -DNDEBUG',
                    f'-DCMAKE_CXX_FLAGS={flags}', '-DCMAKE_EXE_LINKER_FLAGS=-fprofile-instr-generate',
                    '-DBRDFKIT_WERROR=OFF', '-DBRDFKIT_BUILD_BENCH=OFF', '-DBRDFKIT_INSTALL=OFF',
                    '-DBRDFKIT_ROBUSTNESS_TESTS=OFF', '-DBRDFKIT_PYTHON=OFF'], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(['cmake', '--build', tree, '-j', str(jobs)], check=True, stdout=subprocess.DEVNULL)


def profile_env(profile_dir):
    """The environment that sends a run's coverage profiles (and its child
    processes') to profile_dir: the coverage runtime writes one on every
    exit, default.profraw in the working directory unless told."""
    return dict(os.environ, LLVM_PROFILE_FILE=os.path.join(profile_dir, '%p-%m.profraw'))


def gtest_names(exe, profile_dir):
    """The test names of exe; its profile goes to profile_dir."""
    out = subprocess.run([exe, '--gtest_list_tests'], check=True, capture_output=True, text=True,
                         env=profile_env(profile_dir)).stdout
    names, suite = set(), ''
    for line in out.splitlines():
        if not line.strip():
            continue
        if not line.startswith(' '):
            suite = line.split()[0]
        else:
            names.add(suite + line.split()[0])
    return names


def run(cmd, profile_dir, cwd, cpu=None):
    """Runs one command, its profiles (and its child processes') in
    profile_dir; returns an error message, or None."""
    os.makedirs(profile_dir, exist_ok=True)
    env = profile_env(profile_dir)
    # One core per run: the coverage counters are shared by all threads, and
    # several threads incrementing them from several cores slow a run tenfold.
    if cpu is not None and shutil.which('taskset'):
        cmd = ['taskset', '-c', str(cpu)] + cmd
    r = subprocess.run(cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        return f'{" ".join(cmd)} failed (exit {r.returncode}):\n{r.stdout[-4000:]}'
    return None


def side_by_side(jobs, cores):
    """Runs jobs (command, profile_dir, cwd) on as many cores at once, each
    pinned to a core no other running job holds; returns their errors."""
    free = queue.Queue()
    for cpu in sorted(os.sched_getaffinity(0))[:cores]:
        free.put(cpu)

    def one(job):
        cpu = free.get()
        try:
            return run(*job, cpu=cpu)
        finally:
            free.put(cpu)
    with concurrent.futures.ThreadPoolExecutor(cores) as pool:
        return list(pool.map(one, jobs))


def coverage(profile_dir, objects):
    """The (file, line) and (file, line, block, branch) pairs reached."""
    raws = glob.glob(os.path.join(profile_dir, '*.profraw'))
    if not raws:
        fail(f'{profile_dir}: no profiles written')
    data = profile_dir + '.profdata'
    subprocess.run([tool('llvm-profdata', 'llvm-profdata-14'), 'merge', '-sparse', *raws, '-o', data], check=True)
    args = [tool('llvm-cov', 'llvm-cov-14'), 'export', '-format=lcov', f'-instr-profile={data}', objects[0]]
    for o in objects[1:]:
        args += ['-object', o]
    lcov = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    lines, branches, source = set(), set(), None
    for line in lcov.splitlines():
        if line.startswith('SF:'):
            rel = os.path.relpath(line[3:], ROOT)
            source = rel if rel.startswith(LIBRARY_DIRS) and '_test.' not in rel else None
        elif source is None:
            continue
        elif line.startswith('DA:'):
            number, count = line[3:].split(',')[:2]
            if int(count) > 0:
                lines.add((source, int(number)))
        elif line.startswith('BRDA:'):
            number, block, branch, count = line[5:].split(',')
            if count not in ('-', '0'):
                branches.add((source, int(number), block, branch))
    return lines, branches


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--tree', default=os.path.join(ROOT, 'build-coverage'))
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--list', default=SKIPS, help='the list to check (default tests/sanitizer_skips.txt)')
    parser.add_argument('--only', default='',
                        help='comma-separated names of the list to run alone (default all); the others stay out '
                             'of the kept tests too')
    args = parser.parse_args()
    if not 1 <= args.jobs <= 256:
        fail(f'--jobs: {args.jobs} is not between 1 and 256')
    sections = read_skips(args.list)
    skips = [name for name, _ in sections]
    only = [n for n in args.only.split(',') if n]
    for name in only:
        if name not in skips:
            fail(f'--only: "{name}" is not in {args.list}')
    build(args.tree, args.jobs)
    tests_dir = os.path.join(args.tree, 'tests')
    work = tempfile.mkdtemp(prefix='brdfkit-skips-')
    owner = {}
    for exe in EXECUTABLES:
        for name in gtest_names(os.path.join(tests_dir, exe), os.path.join(work, 'list')):
            owner[name] = exe
    def exe_of(pattern):  # GoogleTest names may be patterns ('Set/FitMaterial.*')
        return next((owner[n] for n in sorted(owner) if fnmatch.fnmatchcase(n, pattern)), None)

    ctest_skips = [s for s in skips if '.' not in s]
    objects = [os.path.join(args.tree, 'brdfkit'), os.path.join(args.tree, 'brdfkit_extended')] + \
              [os.path.join(tests_dir, e) for e in EXECUTABLES]
    negative = ':'.join(s for s in skips if '.' in s)
    # The kept runs side by side, each on a core of its own (as the listed
    # tests below): threads of one run on several cores contend for the
    # coverage counters. fit_tests, the longest, first; then the ctest-level
    # stages the sanitizer tree runs and the list does not skip.
    cores = max(1, min(args.jobs, len(os.sched_getaffinity(0))))
    jobs = [([os.path.join(tests_dir, e), f'--gtest_filter=-{negative}'], os.path.join(work, 'kept'), tests_dir)
            for e in sorted(EXECUTABLES, key=lambda e: e != 'fit_tests')]
    listed = subprocess.run(['ctest', '--test-dir', args.tree, '-N'], check=True, capture_output=True,
                            text=True).stdout
    for stage in ('browser_report_explorer',):
        if stage in listed and stage not in ctest_skips:
            jobs.append((['ctest', '--test-dir', args.tree, '-R', f'^{stage}$'], os.path.join(work, 'kept'), args.tree))
    for error in side_by_side(jobs, cores):
        if error:
            fail(error)
    kept_lines, kept_branches = coverage(os.path.join(work, 'kept'), objects)
    print(f'kept tests: {len(kept_lines)} lines, {len(kept_branches)} branches')
    checked = [i for i, name in enumerate(skips) if not only or name in only]
    jobs = []
    for i in checked:
        name, profile = skips[i], os.path.join(work, f'skip{i}')
        if '.' in name and exe_of(name):
            jobs.append(([os.path.join(tests_dir, exe_of(name)), f'--gtest_filter={name}'], profile, tests_dir))
        elif '.' not in name and name in listed:
            jobs.append((['ctest', '--test-dir', args.tree, '-R', f'^{name}$'], profile, args.tree))
        else:
            fail(f'{args.list}: "{name}" is neither a test of {", ".join(EXECUTABLES)} nor a ctest stage')
    # The listed tests run side by side, each on a core of its own.
    errors = side_by_side(jobs, cores)
    for error in errors:
        if error:
            fail(error)
    failed = False
    for i in checked:
        name = skips[i]
        lines, branches = coverage(os.path.join(work, f'skip{i}'), objects)
        only_lines, only_branches = sorted(lines - kept_lines), sorted(branches - kept_branches)
        if only_lines or only_branches:
            failed = failed or sections[i][1] == 'covered'
            print(f'{name} [{sections[i][1]}]: {len(only_lines)} lines and {len(only_branches)} branches no kept test '
                  'runs:')
            for source, number in only_lines[:20]:
                print(f'  {source}:{number}')
            for source, number, _, _ in only_branches[:20]:
                print(f'  {source}:{number} (a branch)')
        else:
            print(f'{name}: covered by the kept tests ({len(lines)} lines, {len(branches)} branches)')
    shutil.rmtree(work, ignore_errors=True)
    return 1 if failed else 0


if __name__ == '__main__':
    try:
        sys.exit(main())
    except subprocess.CalledProcessError as e:
        print(f'{" ".join(map(str, e.cmd))}: exit {e.returncode}', file=sys.stderr)
        sys.exit(2)
