"""Checked readers for every kind of input a user hands canskin (docs/cli.md, "Inputs").

Each reader turns a damaged or hostile input into one error that names the file and the
dotted field, in bounded time and memory, before anything is built from it:

- :mod:`skin.inputs.tomlfile`: TOML documents (scenes, host configs): size, UTF-8,
  nesting, syntax, non-finite floats anywhere;
- :mod:`skin.inputs.fields`: typed, ranged fields of a parsed document (a bool is not an
  int, every number finite and in its range);
- :mod:`skin.inputs.npz`: ``.npz`` archives of ``.npy`` arrays (datasets, reference
  forces): member kinds, dtypes, and declared shapes against the member's size and the
  memory budget before anything is allocated;
- :mod:`skin.inputs.outputs`: where results go: regular files only, errors naming the
  user's path;
- :mod:`skin.inputs.budget`: the memory budget a request or a declared size is checked
  against.
"""
