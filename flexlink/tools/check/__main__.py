"""Entry point of ``python -m flexlink.tools.check``.

``python -m flexlink.tools.check --child NAME FMU TRACE OPTIONS`` runs one check in a child process (see
isolation.py); ``python -m flexlink.tools.check FMU ...`` is the command ``flexlink check``.
"""

import json
import sys

if len(sys.argv) == 6 and sys.argv[1] == "--child":
    from flexlink.tools.check import isolation
    from flexlink.tools.check.driver import run_child

    isolation.install(sys.argv[4])
    result = run_child(sys.argv[2], sys.argv[3], json.loads(sys.argv[5]))
    print("RESULT " + json.dumps(result.as_dict()), flush=True)
    isolation.finished()
    sys.exit(0)

from flexlink.cli import main  # noqa: E402

sys.exit(main(["check", *sys.argv[1:]]))
