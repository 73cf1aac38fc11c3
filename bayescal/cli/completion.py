"""The ``completion`` verb: a shell completion script, made from the command line's own parser.

``eval "$(bayescal completion bash)"`` (in ``~/.bashrc``) completes the verbs, each verb's options, the
shipped examples' names where a spec, design or data set goes, and file names elsewhere.  zsh reads the
same script after ``autoload -U bashcompinit && bashcompinit``.
"""

from __future__ import annotations

import argparse

#: options that take a shipped example's name (or a file)
EXAMPLE_OPTIONS = ("--model", "--design")


def completion_script(parser: argparse.ArgumentParser) -> str:
    """A bash completion function for ``bayescal``: verbs, options per verb, example names."""
    from bayescal.io.resources import examples

    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))  # noqa: SLF001
    verbs = sorted(sub.choices)
    cases = []
    for verb in verbs:
        opts = sorted(o for a in sub.choices[verb]._actions for o in a.option_strings)  # noqa: SLF001
        cases.append(f'        {verb}) opts="{" ".join(opts)}" ;;')
    names = sorted({e.name for e in examples()} | {e.name.split("_")[0] for e in examples()})
    top = " ".join(o for a in parser._actions for o in a.option_strings)  # noqa: SLF001
    return f"""# bash completion for bayescal (bayescal completion bash)
_bayescal() {{
    local cur prev verb opts
    cur="${{COMP_WORDS[COMP_CWORD]}}"
    prev="${{COMP_WORDS[COMP_CWORD-1]}}"
    if [ "$COMP_CWORD" -eq 1 ]; then
        COMPREPLY=( $(compgen -W "{" ".join(verbs)} {top}" -- "$cur") )
        return
    fi
    verb="${{COMP_WORDS[1]}}"
    case "$prev" in
        {"|".join(EXAMPLE_OPTIONS)}|characterize|--copy)
            COMPREPLY=( $(compgen -W "{" ".join(names)}" -- "$cur") $(compgen -f -- "$cur") )
            return ;;
    esac
    case "$verb" in
{chr(10).join(cases)}
        *) opts="" ;;
    esac
    if [[ "$cur" == -* ]]; then
        COMPREPLY=( $(compgen -W "$opts" -- "$cur") )
    else
        COMPREPLY=( $(compgen -f -- "$cur") )
    fi
}}
complete -o filenames -F _bayescal bayescal
"""


def cmd_completion(args) -> int:
    """Print the completion script of the command line ``args.parser`` (the parser that read ``args``)."""
    print(completion_script(args.parser), end="")
    return 0
