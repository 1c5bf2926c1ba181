"""Run files and the manners shared by every tmr command: the ``--out`` directory, ``run.json``, the output files of a
plan, the console (errors, Ctrl-C, progress) and the common flags. A shared package: it never imports a system
package (``tmr.mcdpr``, ``tmr.ccma``).
"""
