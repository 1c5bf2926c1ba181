"""Views of a plan: the :class:`~tmr.views.motion.Motion` type (the one input of every viewer and exporter), the
figures, the GIF, the HTML view and the view flags of the command lines. A shared package: it never imports a system
package (``tmr.mcdpr``, ``tmr.ccma``).
"""
