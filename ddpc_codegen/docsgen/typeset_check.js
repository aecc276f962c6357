// Typeset every pymdownx.arithmatex formula of a built site with the MathJax the site serves, in node, and
// print one line per formula that does not render (a TeX error, an undefined macro), then a count:
//   node typeset_check.js <mathjax es5 folder> <built site>      (tests/test_docs.py runs it)
const fs = require('fs');
const path = require('path');
const [root, site] = process.argv.slice(2);

function pages(dir) {
  return fs.readdirSync(dir, {withFileTypes: true}).flatMap(e =>
    e.isDirectory() ? pages(path.join(dir, e.name)) : e.name.endsWith('.html') ? [path.join(dir, e.name)] : []);
}

const unescape = s => s.replace(/&lt;/g, '<').replace(/&gt;/g, '>').replace(/&quot;/g, '"').replace(/&amp;/g, '&');
const formulas = [];
for (const page of pages(site)) {
  const re = /class="arithmatex">([\s\S]*?)<\/(span|div)>/g;
  for (const m of fs.readFileSync(page, 'utf8').matchAll(re)) formulas.push([page, unescape(m[1]).trim()]);
}
global.MathJax = {loader: {paths: {mathjax: root}, load: ['input/tex', 'output/svg', 'adaptors/liteDOM'], require},
                  tex: {formatError: (jax, err) => { throw err; }}};
require(path.join(root, 'startup.js'));
MathJax.startup.promise.then(() => {
  let bad = 0;
  for (const [page, f] of formulas) {
    const display = f.startsWith('\\[');
    const tex = f.replace(/^\\[[(]|\\[\])]$/g, '');
    try {
      const svg = MathJax.startup.adaptor.outerHTML(MathJax.tex2svg(tex, {display}));
      if (/merror|fill="red"/.test(svg)) throw new Error('an undefined macro or an error node');
    } catch (e) {
      bad++;
      console.log(`${path.relative(site, page)}: ${e.message}: ${tex.slice(0, 100)}`);
    }
  }
  console.log(`${formulas.length} formulas, ${bad} not rendered`);
  process.exit(bad ? 1 : 0);
});
